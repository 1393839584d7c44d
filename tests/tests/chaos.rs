//! Chaos tier: the deployment's binaries as separate processes (seven stage
//! servers and the gateway, `vlnav_e2e::procs`), a simulated Husky driven in
//! real time by the edge agent in this process, and faults injected while
//! the robot is moving:
//!
//! 1. `stage-kill`: a stage server is killed with SIGKILL, then started again
//!    on the same port;
//! 2. `gateway-kill`: the gateway is killed with SIGKILL, then started again
//!    on the same port with the same data directory;
//! 3. `partition`: the link between the edge agent and the gateway (a
//!    `vlnav_e2e::proxy::Proxy`) is blackholed, then cut, then healed;
//! 4. `stage-link`: the link between the gateway and one stage is delayed
//!    (2 s per chunk) or blackholed, then healed;
//! 5. `stage-freeze`: a stage server is frozen with SIGSTOP (it keeps its
//!    connections and answers nothing, not even HTTP/2 pings, like a stuck
//!    handler) and let go (SIGCONT) once the mission has ended. The gateway
//!    runs with a 2 s `--stage-timeout-s`; the mission must fail naming the
//!    stage within 20–25 s, while the stage is still frozen: keepalive
//!    alone would end the first call only after 20 s, and the mission 10 s
//!    of robot time after that.
//!
//! Every run asserts:
//! - (a) the robot is commanded zero no later than `deadman_timeout_s` + one
//!   frame period, in the robot's sensor time, after the last frame that got
//!   a fresh command to move (`vlnav_e2e::stops` defines it), the wheels
//!   reach zero within the braking time after that, it stays still until the
//!   part is back, and no frame ever moves on a command older than the
//!   deadman;
//! - (b) no mission is lost: the mission under way ends SUCCEEDED, or FAILED
//!   with a reason naming the cause (the stage, "gateway restarted"), read
//!   back with GetMission;
//! - (c) once the part is back the robot is attached again (ListRobots) and a
//!   new mission succeeds.
//!
//! Seeds pick the fault's moment within the mission, its duration, the stage,
//! and the robot's simulation seed. `make test` runs one seeded run per
//! scenario; `VLNAV_CHAOS_RUNS=N` runs N (and `VLNAV_CHAOS_SEED` moves the
//! seeds). Each scenario prints one `chaos summary:` line (run with
//! `--nocapture` to see it).

use std::time::Duration;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tokio::time::Instant;
use vlnav_e2e::procs::{ProcStack, StackOptions};
use vlnav_e2e::proxy::Proxy;
use vlnav_e2e::robot::SimRobot;
use vlnav_e2e::stops::{self, Braking};
use vlnav_edge_agent::EdgeOptions;
use vlnav_proto::v1::{
    GetMissionRequest, ListRobotsRequest, Mission, MissionState, SubmitMissionRequest, SubmitMissionResponse,
    submit_mission_request::Instruction,
};

/// One scenario at a time: eight servers and a real-time robot share the machine.
static SERIAL: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Seeded runs per scenario.
fn runs() -> usize {
    std::env::var("VLNAV_CHAOS_RUNS").ok().and_then(|v| v.parse().ok()).filter(|n| *n > 0).unwrap_or(1)
}

fn base_seed() -> u64 {
    std::env::var("VLNAV_CHAOS_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(20_261_125)
}

/// The stages in the order `stage-kill` runs kill them: those every frame of
/// a mission needs first.
const KILL_ORDER: [&str; 7] = ["local-planner", "segmenter", "detector", "subgoal", "planner", "reid", "ingress"];

#[derive(Clone, Debug)]
enum Fault {
    /// SIGKILL the stage, start it again after `down`.
    KillStage { stage: &'static str, down: Duration },
    /// SIGKILL the gateway, start it again after `down`.
    KillGateway { down: Duration },
    /// Blackhole the robot's link for `stall`, then cut it and refuse
    /// connections for `refuse`, then heal it.
    Partition { stall: Duration, refuse: Duration },
    /// Delay (by `delay`) or blackhole (`delay` = None) the gateway's link to
    /// `stage` for `lasting`, then heal it.
    StageLink { stage: &'static str, delay: Option<Duration>, lasting: Duration },
    /// SIGSTOP `stage` until its mission has ended (at most `lasting`), then SIGCONT.
    FreezeStage { stage: &'static str, lasting: Duration },
}

impl Fault {
    /// The instruction whose execution the fault interrupts: one that needs
    /// the faulty part while the robot moves, where there is one.
    fn instruction(&self) -> &'static str {
        match self {
            Fault::KillStage { stage: "detector" | "reid", .. } => "go to the chair",
            Fault::KillStage { stage: "subgoal", .. } => "move 2 m ahead then turn left then move 2 m ahead",
            _ => "move 6 m ahead",
        }
    }

    /// Whether the robot must stop: the fault takes away something every
    /// frame of the mission needs.
    fn stops_the_robot(&self) -> bool {
        match self {
            Fault::KillStage { stage, .. } => matches!(*stage, "local-planner" | "segmenter" | "detector"),
            _ => true,
        }
    }

    /// Whether `m` ended the way this fault allows, saying why.
    fn accepts(&self, m: &Mission) -> Result<(), String> {
        let state = MissionState::try_from(m.state).unwrap_or(MissionState::Unspecified);
        let failed_naming = |what: &str| state == MissionState::Failed && m.reason.contains(what);
        let ok = match self {
            Fault::KillGateway { .. } => failed_naming("gateway restarted"),
            Fault::KillStage { stage, .. } | Fault::StageLink { stage, .. } => {
                state == MissionState::Succeeded || failed_naming(stage)
            }
            // Frozen for longer than a stage may be down: only a failure will
            // do, and it says the stage did not answer.
            Fault::FreezeStage { stage, .. } => failed_naming(stage) && m.reason.contains("did not answer"),
            Fault::Partition { .. } => state == MissionState::Succeeded,
        };
        if ok { Ok(()) } else { Err(format!("mission {} ended {state:?}: {:?}", m.mission_id, m.reason)) }
    }
}

/// What one run found.
#[derive(Debug, Default)]
struct RunResult {
    stop: Option<stops::Stop>,
    stop_expected: bool,
    lost: bool,
    reattached: bool,
    new_mission_succeeded: bool,
    problems: Vec<String>,
}

/// The stack and the robot's link to its gateway.
struct Bench {
    stack: ProcStack,
    edge_link: Proxy,
}

fn edge_options(bench: &Bench, robot_id: &str, seed: u64) -> EdgeOptions {
    EdgeOptions {
        gateway: bench.edge_link.uri(),
        robot_id: robot_id.into(),
        seed,
        lockstep: false,
        // A quarter of the pixels: the faults, not the images, are under test.
        width: Some(320),
        height: Some(240),
        ..EdgeOptions::default()
    }
}

async fn robot_info(bench: &Bench, robot_id: &str) -> Option<vlnav_proto::v1::RobotInfo> {
    let mut fleet = bench.stack.fleet();
    let robots =
        tokio::time::timeout(Duration::from_secs(2), fleet.list_robots(ListRobotsRequest {})).await.ok()?.ok()?;
    robots.into_inner().robots.into_iter().find(|r| r.robot_id == robot_id)
}

/// Waits until the gateway lists the robot as connected, free, and receiving frames.
async fn attached(bench: &Bench, robot_id: &str, within: Duration) -> Result<(), String> {
    let deadline = Instant::now() + within;
    let mut last_frames = None;
    let mut last = None;
    while Instant::now() < deadline {
        if let Some(r) = robot_info(bench, robot_id).await {
            if r.connected && r.active_mission_id.is_empty() && last_frames.is_some_and(|f| r.frames_received > f) {
                return Ok(());
            }
            last_frames = r.connected.then_some(r.frames_received);
            last = Some(r);
        }
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    Err(format!("robot {robot_id} is not attached and free within {within:?}: {last:?}"))
}

async fn submit(
    bench: &Bench,
    robot_id: &str,
    text: &str,
    dry_run: bool,
) -> Result<SubmitMissionResponse, tonic::Status> {
    let mut missions = bench.stack.missions();
    missions
        .submit_mission(SubmitMissionRequest {
            robot_id: robot_id.into(),
            instruction: Some(Instruction::Text(text.into())),
            dry_run,
        })
        .await
        .map(|r| r.into_inner())
}

fn terminal(state: i32) -> bool {
    [MissionState::Succeeded, MissionState::Failed, MissionState::Cancelled, MissionState::Planned]
        .iter()
        .any(|s| *s as i32 == state)
}

/// Reads the mission back until it is finished; the gateway may be down for
/// a while meanwhile.
async fn finished(bench: &Bench, mission_id: &str, within: Duration) -> Result<Mission, String> {
    let deadline = Instant::now() + within;
    let mut last = String::from("never read");
    while Instant::now() < deadline {
        let mut missions = bench.stack.missions();
        let got = tokio::time::timeout(
            Duration::from_secs(2),
            missions.get_mission(GetMissionRequest { mission_id: mission_id.into() }),
        )
        .await;
        match got {
            Ok(Ok(m)) => {
                let m = m.into_inner();
                if terminal(m.state) {
                    return Ok(m);
                }
                last = format!("{:?} {:?}", MissionState::try_from(m.state), m.reason);
            }
            Ok(Err(s)) => last = format!("GetMission: {s}"),
            Err(_) => last = "GetMission timed out".into(),
        }
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    Err(format!("mission {mission_id} did not finish within {within:?} (last seen: {last})"))
}

/// Waits until the robot moves under `mission_id`.
async fn moving_under(bench: &Bench, robot: &SimRobot, mission_id: &str, within: Duration) -> Result<(), String> {
    let deadline = Instant::now() + within;
    while Instant::now() < deadline {
        if robot.latest().is_some_and(|r| r.mission_id == mission_id && stops::moving(&r)) {
            return Ok(());
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let mission = bench.stack.missions().get_mission(GetMissionRequest { mission_id: mission_id.into() }).await;
    let seen = mission.map(|m| {
        let m = m.into_inner();
        format!("{:?} step {} {:?} {:?}", MissionState::try_from(m.state), m.current_step, m.reason, m.clarification)
    });
    Err(format!(
        "the robot did not start moving for mission {mission_id} within {within:?}: the mission is {seen:?}, the robot's last frame {:?}",
        robot.latest()
    ))
}

/// Injects the fault and heals it; returns the sensor time just before the
/// part was back (the robot must be still until then).
async fn inject(
    bench: &mut Bench,
    fault: &Fault,
    robot: &SimRobot,
    mission_id: &str,
    probes: &mut Vec<String>,
) -> Result<f64, String> {
    match fault {
        Fault::KillStage { stage, down } => {
            bench.stack.kill(stage);
            if *stage == "planner" {
                // Submissions while the planner is down are refused, naming
                // it, or accepted and failed naming it: never lost.
                tokio::time::sleep(Duration::from_millis(200)).await;
                match submit(bench, robot.robot_id(), "turn right", true).await {
                    Err(s) if s.message().contains("planner") => {}
                    Err(s) => probes.push(format!("a submission while the planner is down: {s}")),
                    Ok(m) => {
                        if let Err(e) = finished(bench, &m.mission_id, Duration::from_secs(30))
                            .await
                            .and_then(|m| if m.reason.contains("planner") { Ok(()) } else { Err(format!("{m:?}")) })
                        {
                            probes.push(format!("a submission while the planner is down: {e}"));
                        }
                    }
                }
            }
            tokio::time::sleep(*down).await;
            let heal = robot.now();
            bench.stack.restart(stage).await.map_err(|e| format!("{stage} does not start again: {e:#}"))?;
            Ok(heal)
        }
        Fault::KillGateway { down } => {
            bench.stack.kill(vlnav_e2e::procs::GATEWAY);
            tokio::time::sleep(*down).await;
            let heal = robot.now();
            bench
                .stack
                .restart(vlnav_e2e::procs::GATEWAY)
                .await
                .map_err(|e| format!("the gateway does not start again: {e:#}"))?;
            Ok(heal)
        }
        Fault::Partition { stall, refuse } => {
            bench.edge_link.blackhole();
            tokio::time::sleep(*stall).await;
            bench.edge_link.cut();
            tokio::time::sleep(*refuse).await;
            let heal = robot.now();
            bench.edge_link.pass();
            Ok(heal)
        }
        Fault::StageLink { stage, delay, lasting } => {
            let link = bench.stack.proxy(stage).ok_or_else(|| format!("no proxy in front of {stage}"))?;
            match delay {
                Some(d) => link.delay(*d),
                None => link.blackhole(),
            }
            tokio::time::sleep(*lasting).await;
            let heal = robot.now();
            link.pass();
            Ok(heal)
        }
        Fault::FreezeStage { stage, lasting } => {
            bench.stack.freeze(stage).map_err(|e| format!("{e:#}"))?;
            // The mission must end while the stage is still frozen: a call
            // that is never answered fails at the gateway's deadline.
            let ended = finished(bench, mission_id, *lasting).await;
            let heal = robot.now();
            bench.stack.thaw(stage).map_err(|e| format!("{e:#}"))?;
            if let Err(e) = ended {
                probes.push(format!("the mission did not end while {stage} was frozen: {e}"));
            }
            Ok(heal)
        }
    }
}

async fn one_run(bench: &mut Bench, fault: &Fault, run: usize, seed: u64, rng: &mut ChaCha8Rng) -> RunResult {
    let mut out = RunResult { stop_expected: fault.stops_the_robot(), ..Default::default() };
    let robot_id = format!("husky-{run}");
    let robot = SimRobot::start(edge_options(bench, &robot_id, seed));
    let deadman = robot.opts.deadman_timeout_s;
    let period = robot.period();
    let result: Result<(), String> = async {
        attached(bench, &robot_id, Duration::from_secs(60)).await?;
        let mission = submit(bench, &robot_id, fault.instruction(), false).await.map_err(|s| format!("submit: {s}"))?;
        moving_under(bench, &robot, &mission.mission_id, Duration::from_secs(60)).await?;
        // The fault's moment within the mission.
        tokio::time::sleep(Duration::from_millis(rng.random_range(200..1500))).await;
        let at = robot.latest().ok_or("no frame")?;
        if at.mission_id != mission.mission_id || !stops::moving(&at) {
            return Err(format!("the robot was not moving under the mission when the fault came: {at:?}"));
        }
        let fault_stamp = at.stamp;
        let heal_stamp = inject(bench, fault, &robot, &mission.mission_id, &mut out.problems).await?;

        // (b) the mission ends, for a reason a person understands.
        match finished(bench, &mission.mission_id, Duration::from_secs(150)).await {
            Ok(m) => {
                if let Err(e) = fault.accepts(&m) {
                    out.problems.push(e);
                }
            }
            Err(e) => {
                out.lost = true;
                out.problems.push(e);
            }
        }

        // (c) reattached, and a new mission succeeds.
        attached(bench, &robot_id, Duration::from_secs(60)).await?;
        out.reattached = true;
        let next = submit(bench, &robot_id, "turn left", false).await.map_err(|s| format!("new mission: {s}"))?;
        let m = finished(bench, &next.mission_id, Duration::from_secs(90)).await?;
        if m.state == MissionState::Succeeded as i32 {
            out.new_mission_succeeded = true;
        } else {
            out.problems.push(format!("the new mission after the fault ended {:?}: {}", m.state, m.reason));
        }

        // (a) stopped in time, and still until the part was back.
        let records = robot.records();
        let stale = stops::stale_motion(&records, deadman);
        if let Some(r) = stale.first() {
            out.problems.push(format!("{} frames moved on a stale command, the first: {r:?}", stale.len()));
        }
        out.stop = stops::stop_after(&records, fault_stamp);
        if out.stop_expected {
            match &out.stop {
                None => out.problems.push(format!("the robot was never commanded zero after the fault at {fault_stamp:.2}")),
                Some(s) => {
                    if s.commanded_zero >= heal_stamp {
                        out.problems.push(format!("the robot was commanded zero only after the part was back: {s:?}"));
                    }
                    if !s.within_deadman(deadman, period) {
                        out.problems.push(format!(
                            "commanded zero {:.3} s after the last motion command (bound {:.3} s): {s:?}",
                            s.latency(),
                            deadman + period
                        ));
                    }
                    if !s.ramp_within(Braking::default(), period) {
                        out.problems.push(format!("the wheels did not reach zero within the braking time: {s:?}"));
                    }
                    let still_from = s.applied_zero.unwrap_or(s.commanded_zero);
                    let moved = stops::moved_between(&records, still_from, heal_stamp);
                    if let Some(r) = moved.first() {
                        out.problems.push(format!(
                            "{} frames moved between the stop at {still_from:.2} and the heal at {heal_stamp:.2}, the first: {r:?}",
                            moved.len(),
                        ));
                    }
                }
            }
        }
        Ok(())
    }
    .await;
    if let Err(e) = result {
        out.problems.push(e);
    }
    if let Err(e) = robot.stop().await {
        out.problems.push(format!("the edge agent failed: {e:#}"));
    }
    out
}

/// Runs `VLNAV_CHAOS_RUNS` seeded runs of one scenario on one stack, prints
/// its summary line, and fails with every problem found.
async fn scenario(name: &str, opts: StackOptions, plan: impl Fn(usize, &mut ChaCha8Rng) -> Fault) {
    let _serial = SERIAL.lock().await;
    let started = Instant::now();
    let stack = ProcStack::start(opts).await.expect("the servers start");
    let edge_link = Proxy::start(stack.gateway_addr()).await.expect("the robot's link");
    let mut bench = Bench { stack, edge_link };
    let base = base_seed() ^ name.bytes().fold(0u64, |h, b| h.wrapping_mul(31).wrapping_add(b as u64));
    let mut results = Vec::new();
    for run in 0..runs() {
        let seed = base.wrapping_add(run as u64);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let fault = plan(run, &mut rng);
        let t = Instant::now();
        let r = one_run(&mut bench, &fault, run, seed, &mut rng).await;
        println!(
            "chaos run: scenario={name} run={run} seed={seed} fault={fault:?} stop={} lost={} reattached={} \
             new_mission={} wall={:.1}s problems={:?}",
            r.stop.as_ref().map_or("none".into(), |s| format!(
                "z-c={:.3}s a-c={:.3}s",
                s.latency(),
                s.applied_latency().unwrap_or(f64::NAN)
            )),
            r.lost,
            r.reattached,
            r.new_mission_succeeded,
            t.elapsed().as_secs_f64(),
            r.problems
        );
        results.push((seed, fault, r));
    }
    let n = results.len();
    let edge = EdgeOptions::default();
    let (deadman, period) = (edge.deadman_timeout_s, 1.0 / edge.frame_rate);
    let expected: Vec<_> = results.iter().filter(|(_, _, r)| r.stop_expected).collect();
    let within = expected
        .iter()
        .filter(|(_, _, r)| {
            r.stop
                .as_ref()
                .is_some_and(|s| s.within_deadman(deadman, period) && s.ramp_within(Braking::default(), period))
        })
        .count();
    let worst = |f: fn(&stops::Stop) -> f64| {
        expected.iter().filter_map(|(_, _, r)| r.stop.as_ref().map(f)).fold(f64::NAN, f64::max)
    };
    let lost = results.iter().filter(|(_, _, r)| r.lost).count();
    let reattached = results.iter().filter(|(_, _, r)| r.reattached).count();
    let succeeded = results.iter().filter(|(_, _, r)| r.new_mission_succeeded).count();
    println!(
        "chaos summary: scenario={name} runs={n} stops_within_bound={within}/{} worst_stop_latency_s={:.3} \
         worst_applied_zero_s={:.3} missions_lost={lost} reattached={reattached}/{n} \
         new_missions_succeeded={succeeded}/{n} wall={:.0}s",
        expected.len(),
        worst(stops::Stop::latency),
        worst(|s| s.applied_latency().unwrap_or(f64::NAN)),
        started.elapsed().as_secs_f64()
    );
    let failed: Vec<String> = results
        .iter()
        .filter(|(_, _, r)| !r.problems.is_empty())
        .map(|(seed, fault, r)| format!("seed {seed} {fault:?}: {}", r.problems.join("; ")))
        .collect();
    assert!(
        failed.is_empty(),
        "{name}: {} of {n} runs failed:\n{}\n{}",
        failed.len(),
        failed.join("\n"),
        bench.stack.logs(15)
    );
}

fn between(rng: &mut ChaCha8Rng, lo_ms: u64, hi_ms: u64) -> Duration {
    Duration::from_millis(rng.random_range(lo_ms..=hi_ms))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stage_killed_mid_mission_stops_the_robot_and_the_fleet_recovers() {
    scenario("stage-kill", StackOptions::default(), |run, rng| Fault::KillStage {
        stage: KILL_ORDER[run % KILL_ORDER.len()],
        down: between(rng, 500, 3000),
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gateway_killed_mid_mission_stops_the_robot_and_fails_the_mission_by_name() {
    scenario("gateway-kill", StackOptions::default(), |_, rng| Fault::KillGateway { down: between(rng, 500, 3000) })
        .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_partitioned_robot_stops_and_reattaches() {
    scenario("partition", StackOptions::default(), |_, rng| Fault::Partition {
        stall: between(rng, 1000, 6000),
        refuse: between(rng, 300, 2000),
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_or_blackholed_stage_link_stops_the_robot() {
    let opts = StackOptions { proxied: vec!["segmenter", "local-planner"], ..StackOptions::default() };
    scenario("stage-link", opts, |run, rng| {
        let stage = if rng.random_bool(0.5) { "segmenter" } else { "local-planner" };
        // Runs alternate: a slow link, then a dead one.
        let delay = (run % 2 == 0).then_some(Duration::from_secs(2));
        Fault::StageLink { stage, delay, lasting: between(rng, 3000, 6000) }
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_frozen_stage_fails_the_mission_at_the_call_deadline() {
    let opts = StackOptions { gateway_args: vec!["--stage-timeout-s".into(), "2".into()], ..StackOptions::default() };
    scenario("stage-freeze", opts, |run, rng| Fault::FreezeStage {
        stage: if run % 2 == 0 { "local-planner" } else { "segmenter" },
        // Longer than a stage may stay down (10 s of sensor time) plus the
        // first call's deadline, with room to spare.
        lasting: between(rng, 20_000, 25_000),
    })
    .await;
}
