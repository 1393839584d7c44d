//! A ROS 2 robot end to end: `vlnav up --no-robot` (every stage and the
//! gateway, TLS), `vlnav-edge --driver ros2` with the robot's certificate,
//! and a fake Husky A300 written with the real rclpy of ROS 2 Jazzy on Fast
//! DDS (`ros2_robot/fake_a300.py`, from PyPI: deploy/tools.d/ros2.txt).
//!
//! Checks, in the robot's own stamps:
//! - the robot's battery and e-stop reach ListRobots;
//! - a mission is refused (FAILED_PRECONDITION, saying why) while the
//!   robot's e-stop is engaged;
//! - a mission drives the robot: it receives `geometry_msgs/TwistStamped` on
//!   `/a300_0001/cmd_vel` and its odometry advances;
//! - engaging the e-stop mid-mission makes every command zero within one
//!   e-stop message period and one control cycle; releasing it drives again;
//! - a gateway that stops answering (SIGSTOP) makes the command zero within
//!   the deadman timeout and one control cycle; one that is killed leaves
//!   the robot at zero.
//!
//! A second test drives a Husky A200 on Humble (`--ros-distro humble`):
//! `geometry_msgs/Twist` on `/a200_0001/cmd_vel`, held at zero while idle.
//!
//! DDS finds peers by multicast, so the test runs itself again inside its own
//! user and network namespace (`unshare -rn`) that has only loopback, with a
//! multicast route on it: nothing it sends leaves this machine.

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use vlnav_e2e::procs::binaries;
use vlnav_e2e::repo_root;
use vlnav_e2e::ros2::{Cmd, FakeA300, Proc, inside_own_network_namespace, spawn, wait_for, wall_now};
use vlnav_proto::v1::fleet_service_client::FleetServiceClient;
use vlnav_proto::v1::mission_service_client::MissionServiceClient;
use vlnav_proto::v1::submit_mission_request::Instruction;
use vlnav_proto::v1::{GetMissionRequest, ListRobotsRequest, MissionState, RobotInfo, SubmitMissionRequest};
use vlnav_runtime::client::{TracedChannel, channel_with};
use vlnav_runtime::security::{ClientSecurity, ClientTlsArgs};

const TEST: &str = "a_mission_drives_a_ros2_robot_and_its_estop_and_the_deadman_stop_it";
const ROBOT: &str = "a300-1";
const NAMESPACE: &str = "a300_0001";
const DEADMAN_S: f64 = 0.3;
const CONTROL_HZ: f64 = 20.0;
/// The fake robot publishes its e-stop at 10 Hz.
const ESTOP_PERIOD_S: f64 = 0.1;
/// DDS delivery and scheduling on a loaded 2-core machine.
const TRANSPORT_SLACK_S: f64 = 0.15;
/// A control tick that a loaded machine runs late (the stamps are taken when
/// the tick runs).
const TICK_SLACK_S: f64 = 1.0 / CONTROL_HZ;

/// One test's stack at a time: each is a whole `vlnav up` with realistic
/// perception, and the first checks stop latencies on a 2-core machine.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn a_mission_drives_a_ros2_robot_and_its_estop_and_the_deadman_stop_it() {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if inside_own_network_namespace(TEST) {
        let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
        rt.block_on(inside_the_namespace());
    }
}

const HUMBLE_TEST: &str = "a_mission_drives_an_a200_on_humble_with_twist_on_cmd_vel";

/// `--ros-distro humble`: a Husky A200 on Humble takes `geometry_msgs/Twist`
/// on `cmd_vel`. The fake robot is the same rclpy (Jazzy's, the one on PyPI)
/// subscribing Twist: the message and its DDS type are the same on both
/// distributions, so this checks the driver's Humble mode on the wire, not
/// a Humble installation.
#[test]
fn a_mission_drives_an_a200_on_humble_with_twist_on_cmd_vel() {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if inside_own_network_namespace(HUMBLE_TEST) {
        let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
        rt.block_on(humble_inside_the_namespace());
    }
}

async fn humble_inside_the_namespace() {
    const A200: &str = "a200_0001";
    let stack = Stack::start().await;
    let (mut fleet, mut missions) = (stack.fleet.clone(), stack.missions.clone());

    let robot = FakeA300::start_as(A200, 12.0, 23, "humble");
    let log = robot.log.clone();
    let _edge = stack.edge(A200, 23, &["--ros-distro", "humble"]);

    let info =
        wait_for("the Humble robot attached, with frames and its battery", Duration::from_secs(60), async || {
            robot_info(&mut fleet).await.filter(|r| r.connected && r.frames_received > 5 && r.battery.is_some())
        })
        .await;
    assert_eq!(info.driver, "ros2");
    let idle = log.commands();
    assert!(!idle.is_empty() && idle.iter().all(|c| !c.moves()), "Twist held at zero while idle: {idle:?}");

    missions.submit_mission(submit("move 8 m ahead")).await.expect("SubmitMission");
    wait_for("the Humble robot driven 0.5 m by the mission", Duration::from_secs(90), async || {
        (log.odom_x() > 0.5).then_some(())
    })
    .await;
    let cmds = log.commands();
    let moving: Vec<&Cmd> = cmds.iter().filter(|c| c.moves()).collect();
    assert!(!moving.is_empty(), "the robot received motion");
    assert!(moving.iter().all(|c| c.linear > 0.0 && c.linear <= 1.0 + 1e-9), "forward within the limit: {moving:?}");
    // Twist has no header: the robot received no stamp.
    assert!(cmds.iter().all(|c| c.stamp.is_nan()), "a Humble cmd_vel carries no stamp: {:?}", cmds.first());
}

/// `vlnav up --no-robot` in the test's network namespace (every port is
/// free there), with realistic perception: its colour segmenter reads a real
/// camera's frames (the oracle's needs the simulator's label images; the
/// simulated detector, lacking them too, is skipped and the robot drives
/// without person boxes). Operator clients, and the robot's credentials.
struct Stack {
    bin: PathBuf,
    gateway: Proc,
    _data: tempfile::TempDir,
    ca: PathBuf,
    cert: PathBuf,
    key: PathBuf,
    fleet: FleetServiceClient<TracedChannel>,
    missions: MissionServiceClient<TracedChannel>,
}

const GATEWAY_ADDR: &str = "127.0.0.1:50051";

impl Stack {
    async fn start() -> Stack {
        let bin = binaries().expect("the binaries were built outside");
        let data = tempfile::tempdir().unwrap();
        let models =
            std::env::var_os("VLNAV_MODELS_DIR").map(PathBuf::from).unwrap_or_else(|| repo_root().join("models"));
        assert!(
            models.join("minilm").exists(),
            "models are missing in {}: run deploy/fetch-models.sh",
            models.display()
        );
        let mut up = Command::new(bin.join("vlnav"));
        up.args(["up", "--no-robot", "--robot-id", ROBOT, "--perception", "realistic", "--listen", GATEWAY_ADDR])
            .arg("--data-dir")
            .arg(data.path())
            .env("VLNAV_MODELS_DIR", &models)
            .env("VLNAV_LIVE_VIEW", "off")
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::inherit());
        let gateway = spawn("vlnav up --no-robot", up);
        let security = data.path().join("security");
        let (ca, cert, key) = (
            security.join("ca.pem"),
            security.join(format!("robot-{ROBOT}.pem")),
            security.join(format!("robot-{ROBOT}-key.pem")),
        );
        let token = wait_for("vlnav up writes its credentials", Duration::from_secs(120), async || {
            let t = std::fs::read_to_string(security.join("operator.token")).ok()?;
            (key.exists() && std::net::TcpStream::connect(GATEWAY_ADDR).is_ok()).then(|| t.trim().to_string())
        })
        .await;
        let tls = ClientTlsArgs { tls_ca: Some(ca.clone()), tls_client_cert: None, tls_client_key: None };
        let operator = ClientSecurity::new(tls.load().unwrap(), Some(token));
        let channel = channel_with(&format!("https://{GATEWAY_ADDR}"), &operator).unwrap();
        let fleet = FleetServiceClient::new(channel.clone());
        let missions = MissionServiceClient::new(channel);
        Stack { bin, gateway, _data: data, ca, cert, key, fleet, missions }
    }

    /// `vlnav-edge --driver ros2` for the robot under `namespace` on DDS
    /// domain `domain_id`, as a user runs it on the robot's computer, with
    /// `extra` flags.
    fn edge(&self, namespace: &str, domain_id: u32, extra: &[&str]) -> Proc {
        let mut edge = Command::new(self.bin.join("vlnav-edge"));
        edge.args(["--driver", "ros2", "--ros-namespace", namespace, "--robot-id", ROBOT])
            .args(["--gateway", &format!("https://{GATEWAY_ADDR}")])
            .arg("--tls-ca")
            .arg(&self.ca)
            .arg("--tls-client-cert")
            .arg(&self.cert)
            .arg("--tls-client-key")
            .arg(&self.key)
            .args(extra)
            .env("ROS_DOMAIN_ID", domain_id.to_string())
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::inherit());
        spawn(&format!("vlnav-edge --driver ros2 {}", extra.join(" ")), edge)
    }
}

async fn robot_info(fleet: &mut FleetServiceClient<TracedChannel>) -> Option<RobotInfo> {
    let robots = fleet.list_robots(ListRobotsRequest {}).await.ok()?.into_inner().robots;
    robots.into_iter().find(|r| r.robot_id == ROBOT)
}

fn submit(text: &str) -> SubmitMissionRequest {
    SubmitMissionRequest { robot_id: ROBOT.into(), instruction: Some(Instruction::Text(text.into())), dry_run: false }
}

async fn inside_the_namespace() {
    // 1. The stack, without a robot.
    let mut stack = Stack::start().await;
    let (mut fleet, mut missions) = (stack.fleet.clone(), stack.missions.clone());

    // 2. The fake A300.
    let mut a300 = FakeA300::start(NAMESPACE, 12.0, 17);
    let log = a300.log.clone();

    // 3. The edge agent, as a user runs it on the robot's computer.
    let deadman = DEADMAN_S.to_string();
    let rate = CONTROL_HZ.to_string();
    let _edge = stack.edge(NAMESPACE, 17, &["--deadman-timeout-s", &deadman, "--control-rate-hz", &rate]);

    // The robot attached, its frames and battery arrive.
    let info = wait_for("the ROS 2 robot attached, with frames and its battery", Duration::from_secs(60), async || {
        robot_info(&mut fleet).await.filter(|r| r.connected && r.frames_received > 5 && r.battery.is_some())
    })
    .await;
    assert_eq!(info.driver, "ros2");
    let battery = info.battery.unwrap();
    assert!((battery.fraction - 0.87).abs() < 1e-3 && (battery.voltage - 25.6).abs() < 1e-3, "{battery:?}");
    assert!(!battery.low && !info.estop && !info.platform_estop, "{info:?}");
    assert!(log.commands().iter().all(|c| !c.moves()), "nothing moves before a mission");
    assert!(!log.commands().is_empty(), "the edge agent holds cmd_vel at zero while idle");

    // 4. No mission starts while the robot's e-stop is engaged.
    a300.estop(true);
    wait_for("the robot's e-stop in ListRobots", Duration::from_secs(10), async || {
        robot_info(&mut fleet).await.filter(|r| r.estop && r.platform_estop)
    })
    .await;
    let refused = missions.submit_mission(submit("move 5 m ahead")).await.unwrap_err();
    assert_eq!(refused.code(), tonic::Code::FailedPrecondition, "{refused:?}");
    assert!(refused.message().contains("emergency stop engaged"), "{}", refused.message());
    a300.estop(false);
    wait_for("the e-stop released in ListRobots", Duration::from_secs(10), async || {
        robot_info(&mut fleet).await.filter(|r| !r.estop && !r.platform_estop)
    })
    .await;

    // 5. A mission drives it.
    let mission = missions.submit_mission(submit("move 8 m ahead")).await.expect("SubmitMission").into_inner();
    wait_for("the robot driven 0.5 m by the mission", Duration::from_secs(90), async || {
        (log.odom_x() > 0.5).then_some(())
    })
    .await;
    let cmds = log.commands();
    let moving: Vec<&Cmd> = cmds.iter().filter(|c| c.moves()).collect();
    assert!(moving.iter().all(|c| c.linear > 0.0 && c.linear <= 1.0 + 1e-9), "forward within the limit: {moving:?}");
    for c in &moving {
        // TwistStamped carries the edge agent's sensor time: the robot's clock.
        assert!((c.recv - c.stamp).abs() < 1.0, "a command stamped {} arrived at {}", c.stamp, c.recv);
    }

    // 6. The robot's e-stop stops it, whatever the gateway says.
    let engaged = a300.estop(true);
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let info = robot_info(&mut fleet).await.expect("ListRobots");
    assert!(info.estop && info.platform_estop, "{info:?}");
    let cmds = log.commands();
    let first_zero = cmds
        .iter()
        .find(|c| c.stamp >= engaged && !c.moves())
        .copied()
        .expect("a zero command after the e-stop was engaged");
    let estop_bound = ESTOP_PERIOD_S + 1.0 / CONTROL_HZ + TRANSPORT_SLACK_S;
    eprintln!("ros2 e-stop: zero cmd_vel stamped {:.3} s after the e-stop engaged", first_zero.stamp - engaged);
    assert!(first_zero.stamp - engaged <= estop_bound, "zero {:.3} s after the e-stop", first_zero.stamp - engaged);
    let late: Vec<&Cmd> = cmds.iter().filter(|c| c.stamp > engaged + estop_bound && c.moves()).collect();
    assert!(late.is_empty(), "motion commanded while the e-stop was engaged: {late:?}");
    let state = missions.get_mission(GetMissionRequest { mission_id: mission.mission_id.clone() }).await;
    let state = state.expect("GetMission").into_inner().state;
    assert_eq!(state, MissionState::Running as i32, "the mission waits while the robot is held");

    // 7. Released, the mission drives again.
    let released = a300.estop(false);
    wait_for("motion again after the e-stop is released", Duration::from_secs(30), async || {
        log.commands().iter().any(|c| c.recv > released && c.moves()).then_some(())
    })
    .await;
    tokio::time::sleep(Duration::from_millis(300)).await;

    // 8. The gateway freezes (SIGSTOP: its connection stays open, no command
    //    comes): the edge agent's deadman commands zero within its timeout and
    //    one control cycle, in the robot's stamps.
    let pid = libc::pid_t::try_from(stack.gateway.0.id()).expect("a pid");
    // SAFETY: a signal to the child this test spawned.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGSTOP) }, 0, "SIGSTOP to vlnav up");
    let frozen = wall_now();
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let cmds = log.commands();
    let before: Vec<&Cmd> = cmds.iter().filter(|c| c.recv <= frozen).collect();
    assert!(before.last().is_some_and(|c| c.moves()), "the robot was moving when the gateway froze");
    let last_moving = cmds.iter().rposition(|c| c.moves()).expect("the robot moved");
    let first_zero = *cmds.get(last_moving + 1).expect("a zero command after the last motion");
    // The last command answered a frame stamped before the freeze.
    let bound = DEADMAN_S + 1.0 / CONTROL_HZ + TICK_SLACK_S;
    eprintln!(
        "ros2 deadman: zero cmd_vel stamped {:.3} s after the gateway froze (received {:.3} s after; deadman {DEADMAN_S} s + one {:.2} s cycle)",
        first_zero.stamp - frozen,
        first_zero.recv - frozen,
        1.0 / CONTROL_HZ
    );
    assert!(first_zero.stamp - frozen <= bound, "zero stamped {:.3} s after the freeze", first_zero.stamp - frozen);
    assert!(
        first_zero.recv - frozen <= bound + TRANSPORT_SLACK_S,
        "zero received {:.3} s after the freeze",
        first_zero.recv - frozen
    );
    assert!(cmds.iter().filter(|c| c.stamp > first_zero.stamp).count() >= 10, "zero keeps being published");

    // 9. The gateway dies (SIGKILL): the robot stays at zero, the agent reconnecting.
    let _ = stack.gateway.0.kill();
    let killed = wall_now();
    let _ = stack.gateway.0.wait();
    tokio::time::sleep(Duration::from_millis(1000)).await;
    let after: Vec<Cmd> = log.commands().into_iter().filter(|c| c.recv > killed).collect();
    assert!(after.len() >= 10 && after.iter().all(|c| !c.moves()), "zero held after the gateway died: {after:?}");
}
