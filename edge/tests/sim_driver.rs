//! The edge agent with the `sim` driver against a scripted FleetService peer
//! over a real socket: protocol, lockstep determinism, deadman, clamping,
//! e-stop, reconnect.

mod common;

use std::sync::Arc;

use common::{Reply, answer_all, start};
use tokio::sync::mpsc;
use vlnav_edge_agent::{EdgeOptions, EstopSwitch, Hooks, IdleGate, StepRecord, Twist, Verdict, run_episode, run_with};
use vlnav_runtime::CancellationToken;

fn sim_opts(gateway: &str, lockstep: bool, seconds: f64) -> EdgeOptions {
    EdgeOptions {
        gateway: gateway.to_string(),
        lockstep,
        width: Some(160),
        height: Some(120),
        max_sim_time_s: Some(seconds),
        liveness_timeout_s: 5.0,
        ..EdgeOptions::default()
    }
}

/// A fixed command schedule by frame index: forward, turn left, arc right.
fn schedule() -> common::Script {
    Arc::new(|_, k, stamp| {
        let (v, w) = match k {
            0..=9 => (0.8, 0.0),
            10..=19 => (0.3, 1.2),
            _ => (0.9, -0.5),
        };
        Reply::Command { stamp, linear: v, angular: w, idle: false }
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lockstep_sends_hello_then_frames_and_replays_bit_for_bit() {
    let mut runs = Vec::new();
    for _ in 0..2 {
        let token = CancellationToken::new();
        let (uri, log) = start(schedule(), token.clone()).await;
        let records = run_episode(sim_opts(&uri, true, 3.0), CancellationToken::new()).await.unwrap();
        token.cancel();
        let log = log.lock().unwrap();
        assert!(log.protocol_errors.is_empty(), "{:?}", log.protocol_errors);
        assert_eq!(log.hellos.len(), 1);
        let hello = &log.hellos[0];
        assert_eq!((hello.robot_id.as_str(), hello.driver.as_str(), hello.lockstep), ("husky-1", "sim", true));
        let limits = hello.limits.unwrap();
        assert_eq!(
            (limits.max_linear, limits.max_angular, limits.footprint_length, limits.footprint_width),
            (1.0, 2.0, 0.988, 0.670)
        );
        let cam = hello.camera.unwrap();
        assert_eq!((cam.width, cam.height), (160, 120));
        // One frame per 0.1 s of simulated time, each answered, each with truth and labels.
        assert_eq!(log.frames.len(), 30);
        assert_eq!(log.answered.len(), 30);
        for (k, (_, f)) in log.frames.iter().enumerate() {
            let frame = f.frame.as_ref().unwrap();
            assert_eq!(frame.seq, k as u64);
            assert!((frame.stamp - k as f64 * 0.1).abs() < 1e-9, "frame {k} stamp {}", frame.stamp);
            assert!(f.truth.is_some());
            assert_eq!(frame.labels.as_ref().unwrap().instance_ids.len(), 160 * 120 * 2);
        }
        assert_eq!(log.odometry.len(), 30);
        assert_eq!(records.len(), 30);
        runs.push(records);
    }
    let bits = |r: &[StepRecord]| -> Vec<u64> {
        r.iter()
            .flat_map(|s| {
                let t = s.truth.as_ref().unwrap();
                [
                    t.pose.x,
                    t.pose.y,
                    t.pose.theta,
                    s.odom.x,
                    s.odom.y,
                    s.odom.theta,
                    s.applied.linear,
                    s.applied.angular,
                ]
            })
            .map(f64::to_bits)
            .collect()
    };
    assert_eq!(bits(&runs[0]), bits(&runs[1]));
    let last = runs[0].last().unwrap().truth.clone().unwrap();
    assert!(last.path_length_m > 1.5, "the robot drove: {last:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lockstep_commands_with_stale_stamps_trip_the_deadman() {
    let token = CancellationToken::new();
    // Every answer carries the stamp of a frame 0.5 s earlier than the one it answers.
    let script: common::Script =
        Arc::new(|_, _, stamp| Reply::Command { stamp: stamp - 0.5, linear: 0.8, angular: 0.0, idle: false });
    let (uri, log) = start(script, token.clone()).await;
    let records = run_episode(sim_opts(&uri, true, 2.0), CancellationToken::new()).await.unwrap();
    token.cancel();
    assert_eq!(records.len(), 20);
    for r in &records {
        assert_eq!(r.applied, Twist::ZERO);
        // Dropped as stale at the gate: the governor never holds a command.
        assert!(r.verdict.deadman_tripped(), "{:?}", r.verdict);
    }
    let t = records.last().unwrap().truth.clone().unwrap();
    assert_eq!(t.path_length_m, 0.0);
    let log = log.lock().unwrap();
    assert!(log.statuses.iter().any(|s| s.deadman_tripped && !s.estop), "{:?}", log.statuses);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replayed_and_reordered_commands_are_dropped_and_the_robot_stops() {
    let token = CancellationToken::new();
    // Five honest commands, then the peer replays the fifth (same sequence
    // number, fresh stamps) and sends older numbers with fresh stamps.
    let script: common::Script = Arc::new(|_, k, stamp| match k {
        0..=4 => Reply::Numbered { seq: k as u64 + 1, stamp, linear: 0.5 },
        k if k % 2 == 0 => Reply::Numbered { seq: 5, stamp, linear: 0.8 },
        _ => Reply::Numbered { seq: 3, stamp, linear: 0.8 },
    });
    let (uri, _log) = start(script, token.clone()).await;
    let records = run_episode(sim_opts(&uri, true, 2.0), CancellationToken::new()).await.unwrap();
    token.cancel();
    assert_eq!(records.len(), 20);
    assert!(records[1..5].iter().all(|r| matches!(r.verdict, Verdict::Commanded { .. })), "honest commands drive");
    // From the deadman window (0.3 s) after the last honest command on, the robot is stopped.
    for r in &records[8..] {
        assert_eq!(r.applied, Twist::ZERO, "frame {}: {:?}", r.stamp, r.verdict);
        assert_eq!(r.verdict, Verdict::DeadmanTripped);
    }
    // The platform brakes within a few frames (its own deceleration), then stays put.
    let moved_after: f64 = records[12..]
        .windows(2)
        .map(|w| {
            let (a, b) = (w[0].truth.as_ref().unwrap().pose, w[1].truth.as_ref().unwrap().pose);
            ((b.x - a.x).powi(2) + (b.y - a.y).powi(2)).sqrt()
        })
        .sum();
    assert!(moved_after < 1e-9, "the robot moved {moved_after} m on replayed commands");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commands_for_a_mission_never_announced_are_dropped_and_the_robot_stays_stopped() {
    let token = CancellationToken::new();
    // In order and fresh, but for a mission the gateway never announced, or
    // for none at all while moving.
    let script: common::Script = Arc::new(|_, k, _| {
        if k % 2 == 0 {
            Reply::Unannounced { mission: "m-rogue", linear: 0.8 }
        } else {
            Reply::Unannounced { mission: "", linear: 0.8 }
        }
    });
    let (uri, log) = start(script, token.clone()).await;
    let records = run_episode(sim_opts(&uri, true, 2.0), CancellationToken::new()).await.unwrap();
    token.cancel();
    assert_eq!(records.len(), 20);
    assert_eq!(log.lock().unwrap().answered.len(), 20, "every frame was answered");
    for r in &records {
        assert_eq!(r.applied, Twist::ZERO, "frame {}: {:?}", r.stamp, r.verdict);
        assert!(r.verdict.deadman_tripped(), "{:?}", r.verdict);
    }
    assert_eq!(records.last().unwrap().truth.as_ref().unwrap().path_length_m, 0.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commands_above_the_limits_are_clamped_and_ramped() {
    let token = CancellationToken::new();
    let (uri, _log) = start(answer_all(5.0, -9.0), token.clone()).await;
    let records = run_episode(sim_opts(&uri, true, 2.0), CancellationToken::new()).await.unwrap();
    token.cancel();
    let mut prev = Twist::ZERO;
    for r in &records {
        assert!(r.applied.linear <= 1.0 && r.applied.angular >= -2.0, "{:?}", r.applied);
        assert!((r.applied.linear - prev.linear).abs() <= 0.3 + 1e-9, "linear step {:?} → {:?}", prev, r.applied);
        assert!((r.applied.angular - prev.angular).abs() <= 0.6 + 1e-9);
        prev = r.applied;
    }
    assert_eq!(prev, Twist::new(1.0, -2.0));
    // The simulated robot never exceeds its limits either.
    assert!(records.iter().all(|r| r.truth.as_ref().unwrap().twist.linear <= 1.0 + 1e-9));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn realtime_deadman_stops_the_robot_within_timeout_plus_one_cycle() {
    let token = CancellationToken::new();
    // Answer the first 8 frames, then fall silent.
    let script: common::Script =
        Arc::new(
            |_, k, stamp| {
                if k < 8 { Reply::Command { stamp, linear: 0.5, angular: 0.0, idle: false } } else { Reply::Silence }
            },
        );
    let (uri, log) = start(script, token.clone()).await;
    let records = run_episode(sim_opts(&uri, false, 2.0), CancellationToken::new()).await.unwrap();
    token.cancel();
    let last_answered = log.lock().unwrap().answered.last().expect("answered some frames").1;
    assert!(records.iter().any(|r| r.applied.linear > 0.4), "the robot was driving");
    let first_stop = records
        .iter()
        .find(|r| r.stamp > last_answered && r.applied == Twist::ZERO)
        .expect("the deadman stopped the robot");
    assert_eq!(first_stop.verdict, Verdict::DeadmanTripped);
    let timeout_plus_cycle = 0.3 + 0.1;
    assert!(
        first_stop.stamp <= last_answered + timeout_plus_cycle + 1e-9,
        "stopped at {} s, last command {} s",
        first_stop.stamp,
        last_answered
    );
    // And it stays stopped; the body comes to rest.
    assert!(records.iter().filter(|r| r.stamp >= first_stop.stamp).all(|r| r.applied == Twist::ZERO));
    let end = records.last().unwrap().truth.clone().unwrap();
    assert!(end.twist.linear.abs() < 1e-9, "{:?}", end.twist);
    assert!(log.lock().unwrap().statuses.iter().any(|s| s.deadman_tripped));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn estop_holds_zero_until_released_and_is_reported() {
    let token = CancellationToken::new();
    let (uri, log) = start(answer_all(0.5, 0.0), token.clone()).await;
    let estop = EstopSwitch::default();
    estop.engage();
    let (tx, mut rx) = mpsc::unbounded_channel();
    let hooks = Hooks { observer: Some(tx), estop: estop.clone(), ..Hooks::default() };
    let agent = tokio::spawn(run_with(sim_opts(&uri, true, 3.0), CancellationToken::new(), hooks));
    let mut records = Vec::new();
    while let Some(r) = rx.recv().await {
        if records.len() == 10 {
            estop.release();
        }
        records.push(r);
    }
    agent.await.unwrap().unwrap();
    token.cancel();
    // Engaged for the first frames (the release lands within a frame or two of record 10).
    assert!(records[..10].iter().all(|r| r.applied == Twist::ZERO && r.verdict == Verdict::EStop));
    assert!(records[20..].iter().all(|r| r.verdict != Verdict::EStop && r.applied.linear > 0.0));
    let statuses = log.lock().unwrap().statuses.clone();
    assert!(statuses.first().is_some_and(|s| s.estop), "{statuses:?}");
    assert!(statuses.iter().any(|s| !s.estop && !s.deadman_tripped));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_closed_idle_gate_holds_a_lockstep_robot_between_frames_until_opened() {
    let token = CancellationToken::new();
    // Idle answers: the gateway has no mission for this robot.
    let script: common::Script =
        Arc::new(|_, _, stamp| Reply::Command { stamp, linear: 0.0, angular: 0.0, idle: true });
    let (uri, log) = start(script, token.clone()).await;
    let gate = IdleGate::closed();
    let (tx, mut rx) = mpsc::unbounded_channel();
    let hooks = Hooks { observer: Some(tx), idle_gate: Some(gate.clone()), ..Hooks::default() };
    let agent = tokio::spawn(run_with(sim_opts(&uri, true, 1.0), CancellationToken::new(), hooks));
    let first = rx.recv().await.expect("the first frame is answered");
    assert_eq!(first.seq, 0);
    // Closed: no second frame goes out, however long the harness takes.
    tokio::time::sleep(std::time::Duration::from_millis(300)).await;
    assert!(rx.try_recv().is_err(), "the robot waited at the gate");
    assert_eq!(log.lock().unwrap().frames.len(), 1);
    // Open: the next frame follows at once, at the next sensor time.
    gate.open();
    let second = rx.recv().await.expect("the next frame after opening");
    assert_eq!(second.seq, 1);
    assert!((second.stamp - first.stamp - 0.1).abs() < 1e-9, "{} then {}", first.stamp, second.stamp);
    let mut rest = 0;
    while rx.recv().await.is_some() {
        rest += 1;
    }
    agent.await.unwrap().unwrap();
    token.cancel();
    assert_eq!(rest, 8, "the run went on to its 1 s of sensor time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_gateway_is_noticed_and_the_agent_reconnects_holding_still() {
    let token = CancellationToken::new();
    // First attach: answer 5 frames then go silent. Second attach: answer everything.
    let script: common::Script = Arc::new(|attach, k, stamp| {
        if attach == 0 && k >= 5 {
            Reply::Silence
        } else {
            Reply::Command { stamp, linear: 0.5, angular: 0.0, idle: false }
        }
    });
    let (uri, log) = start(script, token.clone()).await;
    let opts = EdgeOptions { liveness_timeout_s: 0.5, reconnect_initial_s: 0.05, ..sim_opts(&uri, true, 1.5) };
    let records = run_episode(opts, CancellationToken::new()).await.unwrap();
    token.cancel();
    let log = log.lock().unwrap();
    assert_eq!(log.hellos.len(), 2, "reconnected once");
    // The frame left unanswered is sent again after reconnecting, at the same
    // sensor time: lockstep time stood still while the link was down.
    let second: Vec<f64> =
        log.frames.iter().filter(|(a, _)| *a == 1).map(|(_, f)| f.frame.as_ref().unwrap().stamp).collect();
    assert!((second[0] - 0.5).abs() < 1e-9, "resumed at {}", second[0]);
    assert_eq!(records.len(), 15);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bad_scenario_or_option_is_an_error_that_says_what() {
    let opts = EdgeOptions { scenario: "atlantis".into(), ..EdgeOptions::default() };
    let e = vlnav_edge_agent::run(opts, CancellationToken::new()).await.unwrap_err();
    assert!(e.to_string().contains("atlantis") && e.to_string().contains("demo"), "{e}");
    let opts = EdgeOptions { deadman_timeout_s: 0.0, ..EdgeOptions::default() };
    let e = vlnav_edge_agent::run(opts, CancellationToken::new()).await.unwrap_err();
    assert!(e.to_string().contains("--deadman-timeout-s"), "{e}");
    let opts = EdgeOptions { lockstep: true, driver: vlnav_edge_agent::DriverKind::Ros1, ..EdgeOptions::default() };
    assert!(
        vlnav_edge_agent::run(opts, CancellationToken::new()).await.unwrap_err().to_string().contains("--lockstep")
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lockstep_paces_idle_frames_at_real_time_and_the_world_stands_still() {
    let token = CancellationToken::new();
    // No mission drives the robot: every answer is idle and names none.
    let script: common::Script =
        Arc::new(|_, _, stamp| Reply::Command { stamp, linear: 0.0, angular: 0.0, idle: true });
    let (uri, _log) = start(script, token.clone()).await;
    let stop = CancellationToken::new();
    let stopper = stop.clone();
    tokio::spawn(async move {
        tokio::time::sleep(std::time::Duration::from_millis(1000)).await;
        stopper.cancel();
    });
    let records = run_episode(sim_opts(&uri, true, 1.0), stop).await.unwrap();
    token.cancel();
    // A second of wall time holds about ten idle frames at 10 Hz: paced, not
    // as fast as the gateway answers (docs/simulation.md "Time").
    assert!((5..=12).contains(&records.len()), "{} idle frames in one second", records.len());
    assert!(records.iter().all(|r| r.idle));
    // The world stood still, its clock included, so the episode (1 s of
    // simulated time) never ran out.
    let first = &records[0];
    for r in &records {
        assert_eq!(r.stamp, first.stamp);
        assert_eq!(r.truth.as_ref().unwrap().pose, first.truth.as_ref().unwrap().pose);
    }
}
