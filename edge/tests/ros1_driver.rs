//! The `vlnav-edge` binary with the `ros1` driver against a real `roscore`:
//! a rospy node publishes RealSense-like images and odometry, a scripted
//! FleetService peer answers frames, and `rostopic echo /cmd_vel` records
//! what the robot is told. Checks clamping to the Husky's limits and that
//! the deadman zeroes `/cmd_vel` within timeout + one control cycle once the
//! commands stop.
//!
//! Needs the Debian packages listed in `.ci/apt/edge-agent.txt`.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::Reply;
use vlnav_runtime::CancellationToken;

/// Kills the child process when dropped (the test may panic).
struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `roscore` started as the leader of its own process group. It is a
/// roslaunch that forks `rosmaster` and `rosout`; killing only its pid leaves
/// both running. When dropped: SIGINT to the whole group (roslaunch's own
/// shutdown), then SIGKILL to whatever of the group is left after 5 s.
struct ProcGroup(Child);

impl ProcGroup {
    fn spawn(name: &'static str, mut cmd: Command) -> ProcGroup {
        use std::os::unix::process::CommandExt;
        cmd.process_group(0);
        ProcGroup(spawn_child(name, cmd))
    }

    /// The group's id (the child's pid), never 0 or 1, which would name other groups.
    fn pgid(&self) -> Option<libc::pid_t> {
        libc::pid_t::try_from(self.0.id()).ok().filter(|&p| p > 1)
    }

    /// Signals the group whose id is the child's pid; never any other group.
    fn signal_group(&self, signal: libc::c_int) -> bool {
        // SAFETY: plain syscalls on a pid we spawned; a negative pid names its group.
        self.pgid().is_some_and(|g| unsafe { libc::getpgid(g) == g && libc::kill(-g, signal) == 0 })
    }

    /// True while any process of the group is alive (kill with signal 0 probes).
    fn group_alive(&self) -> bool {
        // SAFETY: signal 0 only checks that the group exists.
        self.pgid().is_some_and(|g| unsafe { libc::kill(-g, 0) == 0 })
    }
}

impl Drop for ProcGroup {
    fn drop(&mut self) {
        self.signal_group(libc::SIGINT);
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            // Reap the leader as soon as it exits, so a zombie does not keep the group "alive".
            let _ = self.0.try_wait();
            if !self.group_alive() {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        if let Some(g) = self.pgid() {
            // SAFETY: as above; the group is ours and still alive past its grace period.
            unsafe { libc::kill(-g, libc::SIGKILL) };
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn ros_env(cmd: &mut Command, master: &str, home: &std::path::Path) {
    cmd.env("ROS_MASTER_URI", master)
        .env("ROS_HOSTNAME", "127.0.0.1")
        .env("ROS_HOME", home)
        .env("ROS_LOG_DIR", home.join("log"))
        .env("PYTHONUNBUFFERED", "1")
        .env_remove("ROS_IP");
}

fn spawn(name: &'static str, cmd: Command) -> Proc {
    Proc(spawn_child(name, cmd))
}

fn spawn_child(name: &'static str, mut cmd: Command) -> Child {
    match cmd.spawn() {
        Ok(c) => c,
        Err(e) => panic!(
            "cannot run `{name}`: {e}. The ros1 driver test needs ROS 1: apt-get install $(grep -v '^#' .ci/apt/edge-agent.txt)"
        ),
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// One `rostopic echo -p` row: receipt time (s) and the twist.
#[derive(Debug, Clone, Copy)]
struct Row {
    t: f64,
    linear: f64,
    angular: f64,
}

fn parse_rows(lines: &[String]) -> Vec<Row> {
    lines
        .iter()
        .filter(|l| !l.starts_with('%') && !l.trim().is_empty())
        .filter_map(|l| {
            let c: Vec<&str> = l.trim().split(',').collect();
            if c.len() < 7 {
                return None;
            }
            Some(Row { t: c[0].parse::<f64>().ok()? * 1e-9, linear: c[1].parse().ok()?, angular: c[6].parse().ok()? })
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ros1_driver_clamps_and_its_deadman_zeroes_cmd_vel_on_a_real_roscore() {
    let home = tempfile::tempdir().unwrap();
    let port = free_port();
    let master = format!("http://127.0.0.1:{port}");

    let mut roscore = Command::new("roscore");
    roscore.args(["-p", &port.to_string()]).stdout(Stdio::null()).stderr(Stdio::null());
    ros_env(&mut roscore, &master, home.path());
    let _roscore = ProcGroup::spawn("roscore", roscore);
    let started = Instant::now();
    loop {
        let mut list = Command::new("rostopic");
        list.arg("list").stdout(Stdio::null()).stderr(Stdio::null());
        ros_env(&mut list, &master, home.path());
        if list.status().map(|s| s.success()).unwrap_or(false) {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(30), "roscore did not come up on port {port} within 30 s");
        std::thread::sleep(Duration::from_millis(300));
    }

    // The Debian interpreter: rospy lives in its dist-packages, not in other Pythons on PATH.
    let python = if std::path::Path::new("/usr/bin/python3").exists() { "/usr/bin/python3" } else { "python3" };
    let mut husky = Command::new(python);
    husky
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fake_husky.py"))
        .stdout(Stdio::null())
        .stderr(Stdio::inherit());
    ros_env(&mut husky, &master, home.path());
    let _husky = spawn("python3 fake_husky.py", husky);

    let mut echo = Command::new("rostopic");
    echo.args(["echo", "-p", "/cmd_vel"]).stdout(Stdio::piped()).stderr(Stdio::null());
    ros_env(&mut echo, &master, home.path());
    let mut echo = spawn("rostopic echo", echo);
    let lines = Arc::new(Mutex::new(Vec::<String>::new()));
    {
        let out = echo.0.stdout.take().unwrap();
        let lines = lines.clone();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                lines.lock().unwrap().push(l);
            }
        });
    }

    // Frames 0–14: far above the limits; 15–29: 0.5 m/s; then silence.
    let token = CancellationToken::new();
    let script: common::Script = Arc::new(|_, k, stamp| match k {
        0..15 => Reply::Command { stamp, linear: 5.0, angular: 9.0, idle: false },
        15..30 => Reply::Command { stamp, linear: 0.5, angular: 0.0, idle: false },
        _ => Reply::Silence,
    });
    let (uri, log) = common::start(script, token.clone()).await;

    let mut edge = Command::new(env!("CARGO_BIN_EXE_vlnav-edge"));
    edge.args([
        "--driver",
        "ros1",
        "--gateway",
        &uri,
        "--robot-id",
        "husky-ros",
        "--control-rate-hz",
        "20",
        "--liveness-timeout-s",
        "60",
    ])
    .env("RUST_LOG", "warn")
    .stdout(Stdio::null())
    .stderr(Stdio::inherit());
    ros_env(&mut edge, &master, home.path());
    let edge = spawn("vlnav-edge", edge);

    let waited = Instant::now();
    loop {
        let answered = log.lock().unwrap().answered.len();
        if answered >= 30 {
            break;
        }
        assert!(
            waited.elapsed() < Duration::from_secs(60),
            "the edge agent forwarded only {answered} frames in 60 s (hellos: {:?})",
            log.lock().unwrap().hellos
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // Let the deadman act, then stop everything.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    drop(edge);
    std::thread::sleep(Duration::from_millis(300));
    drop(echo);
    token.cancel();

    let log = log.lock().unwrap();
    assert!(log.protocol_errors.is_empty(), "{:?}", log.protocol_errors);
    let hello = &log.hellos[0];
    assert_eq!((hello.robot_id.as_str(), hello.driver.as_str(), hello.lockstep), ("husky-ros", "ros1", false));
    let (_, first) = &log.frames[0];
    let f = first.frame.as_ref().unwrap();
    assert_eq!((f.rgb.as_ref().unwrap().width, f.rgb.as_ref().unwrap().height), (32, 24));
    assert_eq!(&f.rgb.as_ref().unwrap().data[..3], &[200, 30, 30]);
    let d = &f.depth.as_ref().unwrap().data_mm;
    assert_eq!(u16::from_le_bytes([d[2], d[3]]), 1510);
    assert!((f.camera.as_ref().unwrap().intrinsics.unwrap().fx - 17.2).abs() < 1e-9);
    assert!(f.odom.is_some());

    let rows = parse_rows(&lines.lock().unwrap());
    assert!(rows.len() > 40, "rostopic echo saw {} /cmd_vel messages", rows.len());
    // Clamping: never above the Husky's limits, and the limits are reached.
    for r in &rows {
        assert!(r.linear.abs() <= 1.0 + 1e-9 && r.angular.abs() <= 2.0 + 1e-9, "{r:?} exceeds the limits");
    }
    assert!(rows.iter().any(|r| r.linear == 1.0 && r.angular == 2.0), "the clamped command reaches the limits");
    // Acceleration: the first motion is a ramp, not a jump to the limit
    // (3 m/s² over a 50 ms control cycle is 0.15 m/s; allow scheduling jitter).
    let first_motion = rows.iter().find(|r| r.linear != 0.0).expect("the robot was commanded to move");
    assert!(first_motion.linear <= 0.35, "first /cmd_vel after rest {first_motion:?}");
    assert!(rows.iter().any(|r| (r.linear - 0.5).abs() < 1e-9), "the 0.5 m/s phase reached /cmd_vel");

    // Deadman: once the commands stop, /cmd_vel is zero within timeout + one control cycle.
    let last_command_stamp = log.answered.last().unwrap().1;
    let last_moving = rows.iter().rposition(|r| r.linear != 0.0 || r.angular != 0.0).unwrap();
    assert!(last_moving + 1 < rows.len(), "no zero /cmd_vel after the commands stopped");
    let stop = rows[last_moving + 1];
    let deadline = last_command_stamp + 0.3 + 1.0 / 20.0;
    eprintln!("deadman: zero /cmd_vel received {:.3} s after the last command's stamp", stop.t - last_command_stamp);
    // Delivery through TCPROS to rostopic adds a little latency on a loaded machine.
    let transport_slack = 0.1;
    assert!(
        stop.t <= deadline + transport_slack,
        "zero /cmd_vel arrived {:.3} s after the last command's stamp (timeout 0.3 s + cycle 0.05 s)",
        stop.t - last_command_stamp
    );
    assert!(rows[last_moving + 1..].iter().all(|r| r.linear == 0.0 && r.angular == 0.0));
    assert!(rows[last_moving + 1..].len() >= 10, "zero keeps being published while the deadman holds");
    assert!(log.statuses.iter().any(|s| s.deadman_tripped), "deadman reported to the gateway: {:?}", log.statuses);
}
