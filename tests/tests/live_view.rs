//! What the robot saw, through third-party clients: a live-view client
//! written against the Foxglove WebSocket protocol's published library (npm
//! `@foxglove/ws-protocol`) subscribes to a running stack's topics during a
//! mission, and the mission's MCAP recording is read back with the `mcap`
//! Python library and its protobuf decoder, then replayed through a fresh
//! stack: the same commands, and a difference once behaviour changes
//! (docs/observability.md). Its first frames then drive a second robot that
//! sends them again, as the fleet benchmark's `--replay` robots do.

use std::process::{Command, Stdio};
use std::time::Duration;

use vlnav::replay::{ReplayArgs, read_frames, replay};
use vlnav_e2e::{TestStack, repo_root, tool};
use vlnav_edge_agent::replay::{Recorded, run_replay};
use vlnav_edge_agent::{Codecs, ColourCodec, DepthCodec, EdgeOptions, Hooks};
use vlnav_gateway::config::ExecutorParams;
use vlnav_proto::v1::{MissionState, SubmitMissionRequest, submit_mission_request::Instruction};

const ROBOT: &str = "husky-1";

fn node_client(url: &str) -> std::process::Child {
    let modules = repo_root().join(".node/node_modules");
    assert!(
        modules.join("@foxglove/ws-protocol").exists(),
        "{} lacks @foxglove/ws-protocol: run deploy/setup-tools.sh (or `make test`) first",
        modules.display()
    );
    Command::new("node")
        .arg(repo_root().join("tests/tests/live_view/client.cjs"))
        .args([url, ROBOT, "120", "5"])
        .env("NODE_PATH", &modules)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("node runs (Debian's nodejs, deploy/setup-system.sh)")
}

/// Submits `text` for `robot`; the mission's id.
async fn submit(t: &TestStack, robot: &str, text: &str) -> String {
    let request = SubmitMissionRequest {
        robot_id: robot.into(),
        instruction: Some(Instruction::Text(text.into())),
        dry_run: false,
    };
    let submitted = t.missions().await.submit_mission(request).await;
    submitted.unwrap_or_else(|e| panic!("SubmitMission for {robot}: {e}")).into_inner().mission_id
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_mission_is_seen_live_and_its_recording_reads_back_with_the_mcap_library() {
    let t = TestStack::start(|a| {
        a.live_view = "127.0.0.1:0".into();
        a.record = true;
    })
    .await;
    let addr = t.stack.live_view_addr().expect("the live view is on");
    let client = node_client(&format!("ws://{addr}"));

    let mission_id = submit(&t, ROBOT, "go to the bicycle").await;
    let (_, mission) = t.follow(&mission_id, Duration::from_secs(240)).await;
    assert_eq!(mission.state, MissionState::Succeeded as i32, "{}", mission.reason);

    // The live view, as a client of the protocol's library saw it.
    let out = tokio::task::spawn_blocking(move || client.wait_with_output()).await.unwrap().expect("node client");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "live-view client: {}\n{stdout}", String::from_utf8_lossy(&out.stderr));
    let live: serde_json::Value = serde_json::from_str(stdout.trim()).expect("the client prints JSON");
    assert_eq!(live["server"], "vlnav");
    for (topic, schema) in [
        ("camera/image", "foxglove.CompressedImage"),
        ("camera/annotations", "foxglove.ImageAnnotations"),
        ("camera/depth", "foxglove.RawImage"),
        ("segmenter/no_go", "foxglove.PointCloud"),
        ("scene", "foxglove.SceneUpdate"),
        ("tf", "foxglove.FrameTransforms"),
        ("cmd_vel", "vlnav.v1.VelocityCommand"),
        ("mission/status", "vlnav.MissionStatus"),
    ] {
        let seen = &live["topics"][format!("/{ROBOT}/{topic}")];
        assert_eq!(seen["schema"], schema, "{topic}: {live}");
        assert!(seen["count"].as_u64().unwrap_or(0) >= 5, "{topic} delivered too little: {live}");
    }
    assert!(live["topics"][format!("/{ROBOT}/camera/image")]["bytes"].as_u64().unwrap() > 5 * 5_000, "{live}");
    assert_eq!(live["status"]["mission_id"], mission_id.as_str(), "{live}");

    // The recording: named by GetMission, finished, and readable by a third party.
    assert_eq!(mission.recordings.len(), 1, "{:?}", mission.recordings);
    let file = std::path::PathBuf::from(&mission.recordings[0]);
    assert!(file.starts_with(t.data.path()), "{} is in the gateway's data directory", file.display());
    t.stack.gateway.flush_view();
    let out = Command::new(tool("python"))
        .arg(repo_root().join("tests/tests/live_view/check_recording.py"))
        .arg(&file)
        .output()
        .expect("python runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "check_recording.py: {}", String::from_utf8_lossy(&out.stderr));
    let rec: serde_json::Value = serde_json::from_str(stdout.trim()).expect("the checker prints JSON");
    let topics = &rec["topics"];
    let facts = &rec["facts"];
    let metrics = mission.metrics.expect("metrics");
    let frames = metrics.frames as u64;
    for (topic, schema, encoding, count) in [
        ("sensor_frame", "vlnav.v1.SensorFrame", "protobuf", Some(frames)),
        ("cmd_vel", "vlnav.v1.VelocityCommand", "protobuf", Some(frames)),
        ("camera/image", "foxglove.CompressedImage", "protobuf", Some(frames)),
        ("camera/annotations", "foxglove.ImageAnnotations", "protobuf", Some(frames)),
        ("camera/depth", "foxglove.RawImage", "protobuf", Some(frames)),
        ("camera/calibration", "foxglove.CameraCalibration", "protobuf", Some(frames)),
        ("segmenter/no_go", "foxglove.PointCloud", "protobuf", Some(frames)),
        ("scene", "foxglove.SceneUpdate", "protobuf", Some(frames)),
        ("tf", "foxglove.FrameTransforms", "protobuf", Some(frames)),
        ("truth/pose", "foxglove.PoseInFrame", "protobuf", Some(frames)),
        ("mission/status", "vlnav.MissionStatus", "jsonschema", Some(frames)),
        ("mission/plan", "vlnav.v1.ActionPlan", "protobuf", Some(1)),
        ("mission/events", "vlnav.v1.MissionEvent", "protobuf", None),
    ] {
        let entry = &topics[format!("/{ROBOT}/{topic}")];
        assert_eq!(entry["schema"], schema, "{topic}: {rec}");
        assert_eq!(entry["schema_encoding"], encoding, "{topic}: {rec}");
        if let Some(n) = count {
            assert_eq!(entry["count"].as_u64(), Some(n), "{topic}: one message per frame of the mission: {rec}");
        }
    }
    assert_eq!(facts["frames"].as_u64(), Some(frames));
    assert_eq!(facts["frame_seqs_increasing"], true);
    assert_eq!(facts["command_mission_ids"], serde_json::json!([mission_id]));
    assert_eq!(facts["jpeg_images"].as_u64(), Some(frames), "every camera image is a JPEG");
    assert!(facts["target_boxes"].as_u64().unwrap() >= 3, "the tracked bicycle is highlighted: {facts}");
    assert!(facts["labels"].as_array().unwrap().iter().any(|l| l == "TARGET bicycle"), "{facts}");
    assert_eq!(facts["plan_steps"].as_u64(), Some(1), "{facts}");
    let events: Vec<&str> = facts["events"].as_array().unwrap().iter().filter_map(|e| e.as_str()).collect();
    assert_eq!(events.first(), Some(&"step_started"), "{events:?}");
    assert_eq!(events.last(), Some(&"finished"), "{events:?}");
    assert!(events.contains(&"target_seen"), "{events:?}");
    let duration = facts["last_stamp"].as_f64().unwrap() - facts["first_stamp"].as_f64().unwrap();
    assert!(
        (duration - metrics.duration_s).abs() < 0.5,
        "recorded {duration:.1} s of a {:.1} s mission",
        metrics.duration_s
    );
    assert_eq!(facts["metadata"]["vlnav.mission"]["mission_id"], mission_id.as_str());
    let states = facts["states"].as_array().expect("mission states");
    assert_eq!(states.first().and_then(|s| s.as_str()), Some("running"), "{states:?}");
    assert_eq!(states.last().and_then(|s| s.as_str()), Some("succeeded"), "{states:?}");

    // Replay: the recorded frames through a fresh stack give the recorded commands…
    let mut args =
        ReplayArgs { file: file.clone(), perception: None, show: 5, json: false, executor: ExecutorParams::default() };
    let same = replay(&args).await.expect("replay");
    assert_eq!(same.perception, "oracle", "the recording says which perception it ran with");
    assert_eq!(same.frames as u64, frames);
    assert!(same.identical(), "record != replay:\n{same}");
    assert_eq!(same.replayed_state, "succeeded");
    // … and a change of behaviour shows up as a difference.
    args.executor.default_d_s = 1.0;
    let changed = replay(&args).await.expect("replay with another stopping distance");
    assert!(changed.plan_matches && changed.differing > 0, "a nearer stop must change some commands:\n{changed}");
    assert!(changed.first[0].index > 0, "the first frames drive the same way: {changed}");

    // The recording as the load generator's robot (`vlnav bench fleet
    // --replay`): its frames sent again in real time, with JPEG colour and
    // depth in quantised disparity (the compressed link of
    // docs/architecture.md, "Frames"), by a robot whose odometry follows the
    // commands, so a MOVE drives to its end.
    let frames = read_frames(&file, 20).expect("the recording's first frames");
    assert_eq!(frames.len(), 20);
    let codecs =
        Codecs { colour: ColourCodec::Jpeg, jpeg_quality: 80, depth: DepthCodec::Disparity, ..Codecs::default() };
    let recorded = Recorded::new(frames, codecs).expect("the frames convert");
    let opts = EdgeOptions {
        gateway: t.uri(),
        robot_id: "husky-2".into(),
        lockstep: false,
        frame_rate: 10.0,
        tls: t.security().robot("husky-2").expect("a certificate for the second robot"),
        ..EdgeOptions::default()
    };
    let (tx, mut steps) = tokio::sync::mpsc::unbounded_channel();
    let stop = vlnav_runtime::CancellationToken::new();
    let robot = tokio::spawn({
        let stop = stop.clone();
        async move { run_replay(&opts, recorded, stop, Hooks { observer: Some(tx), ..Hooks::default() }).await }
    });
    t.wait_for_robot("husky-2").await;
    let mission_id = submit(&t, "husky-2", "move 1.5 m ahead").await;
    let (_, mission) = t.follow(&mission_id, Duration::from_secs(120)).await;
    stop.cancel();
    robot.await.unwrap().expect("the replaying robot ends cleanly");
    assert_eq!(mission.state, MissionState::Succeeded as i32, "{}", mission.reason);
    let mut last = None;
    while let Ok(step) = steps.try_recv() {
        assert!(step.truth.is_none(), "a replaying robot knows no ground truth");
        last = Some(step);
    }
    let last = last.expect("the replaying robot reported its steps");
    assert!(last.seq > 20, "the 20 frames were sent again from the start: seq {}", last.seq);
    assert!(
        (last.odom.x - 1.5).abs() < 0.3 && last.odom.y.abs() < 0.1,
        "the odometry followed the MOVE: {:?}",
        last.odom
    );
}
