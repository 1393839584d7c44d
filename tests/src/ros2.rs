//! A ROS 2 robot for the end-to-end tests (`tests/tests/ros2_robot.rs`,
//! `tests/tests/real_robot.rs`): the fake Husky A300 written with the real
//! rclpy of ROS 2 Jazzy on Fast DDS (`tests/tests/ros2_robot/fake_a300.py`,
//! from PyPI: deploy/tools.d/ros2.txt), what it prints, and a test run again
//! inside a user and network namespace of its own: DDS finds peers by
//! multicast, and there, with only loopback and a multicast route on it,
//! nothing it sends leaves this machine.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use serde_json::Value;

use crate::procs::binaries;
use crate::repo_root;

/// Set (to the test's name) in the run inside the namespace.
const INSIDE: &str = "VLNAV_ROS2_TEST_NETNS";

/// Runs test `test` of this test executable again inside a user and
/// network namespace of its own (`unshare -rn`) that has only loopback,
/// with a multicast route on it; the deployment's binaries are built first,
/// outside (cargo needs the namespace's outside: its registry, its
/// jobserver). Returns `true` in the run inside, where the caller runs the
/// test's body; outside it returns `false` once the run inside passed, and
/// panics when it failed.
pub fn inside_own_network_namespace(test: &str) -> bool {
    if std::env::var(INSIDE).is_ok_and(|v| v == test) {
        // /proc/net/dev lists this network namespace's interfaces (/sys/class/net
        // shows the namespace sysfs was mounted in).
        let interfaces: Vec<String> = std::fs::read_to_string("/proc/net/dev")
            .expect("/proc/net/dev")
            .lines()
            .skip(2)
            .filter_map(|l| l.split(':').next().map(|n| n.trim().to_string()))
            .collect();
        assert_eq!(interfaces, vec!["lo".to_string()], "the test's network namespace has only loopback");
        return true;
    }
    let bin = binaries().expect("the deployment's binaries build");
    let exe = std::env::current_exe().expect("the test executable's path");
    let script = "ip link set lo up && ip route add 224.0.0.0/4 dev lo && exec \"$0\" \"$@\"";
    let status = Command::new("unshare")
        .args(["--user", "--map-root-user", "--net", "sh", "-c", script])
        .arg(&exe)
        .args(["--exact", test, "--nocapture", "--test-threads=1"])
        .env(INSIDE, test)
        .env("VLNAV_BIN_DIR", &bin)
        .status()
        .unwrap_or_else(|e| {
            panic!("cannot run unshare: {e}. The ROS 2 tests run DDS in a network namespace of their own: they need util-linux's unshare, iproute2's ip and unprivileged user namespaces")
        });
    assert!(status.success(), "{test} failed inside its network namespace (its output is above): {status}");
    false
}

/// Kills the child when dropped (the test may panic).
pub struct Proc(pub Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

pub fn spawn(what: &str, mut cmd: Command) -> Proc {
    Proc(cmd.spawn().unwrap_or_else(|e| panic!("cannot start {what}: {e}")))
}

/// The wall clock, s since 1970: the fake robot's clock.
pub fn wall_now() -> f64 {
    SystemTime::now().duration_since(SystemTime::UNIX_EPOCH).expect("the clock is after 1970").as_secs_f64()
}

/// Polls `f` every 0.1 s until it gives a value; panics after `limit`.
pub async fn wait_for<T>(what: &str, limit: Duration, mut f: impl AsyncFnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(v) = f().await {
            return v;
        }
        assert!(start.elapsed() < limit, "{what}: not within {} s", limit.as_secs());
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// The venv's Python with rclpy, or a failure saying how to install it.
pub fn ros2_python() -> PathBuf {
    let python = repo_root().join(".venv/bin/python");
    let ok = Command::new(&python)
        .args(["-c", "import rclpy, geometry_msgs.msg, nav_msgs.msg, sensor_msgs.msg, std_msgs.msg"])
        .env("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "{} cannot import rclpy and the message packages: run deploy/setup-tools.sh (or `make test`), which installs deploy/tools.d/ros2.txt",
        python.display()
    );
    python
}

/// The fake A300, running: its log and its stdin (the e-stop).
pub struct FakeA300 {
    pub proc: Proc,
    pub log: RobotLog,
    stdin: ChildStdin,
}

impl FakeA300 {
    /// Starts it under `namespace` in DDS domain `domain_id`, a wall
    /// `wall_x_m` ahead of its start in its camera's view, as on Jazzy
    /// (`geometry_msgs/TwistStamped` on `cmd_vel`).
    pub fn start(namespace: &str, wall_x_m: f64, domain_id: u32) -> Self {
        Self::start_as(namespace, wall_x_m, domain_id, "jazzy")
    }

    /// As [`FakeA300::start`], with the platform's `cmd_vel` of `distro`:
    /// `jazzy` (TwistStamped) or `humble` (Twist, as a Husky A200 on Humble).
    pub fn start_as(namespace: &str, wall_x_m: f64, domain_id: u32, distro: &str) -> Self {
        let mut a300 = Command::new(ros2_python());
        a300.arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ros2_robot/fake_a300.py"))
            .args(["--namespace", namespace, "--wall-x", &wall_x_m.to_string(), "--distro", distro])
            .env("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
            .env("ROS_DOMAIN_ID", domain_id.to_string())
            .env("PYTHONUNBUFFERED", "1")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit());
        let mut proc = spawn("the fake A300 (rclpy)", a300);
        let log = RobotLog::default();
        log.follow(proc.0.stdout.take().expect("piped"));
        let stdin = proc.0.stdin.take().expect("piped");
        Self { proc, log, stdin }
    }

    /// Engages or releases the robot's e-stop; returns when, on the wall clock.
    pub fn estop(&mut self, on: bool) -> f64 {
        let at = wall_now();
        writeln!(self.stdin, "estop {}", if on { "on" } else { "off" }).expect("the fake robot reads its stdin");
        self.stdin.flush().expect("the fake robot reads its stdin");
        at
    }
}

/// What the fake robot printed: JSON lines.
#[derive(Clone, Default)]
pub struct RobotLog(Arc<Mutex<Vec<Value>>>);

impl RobotLog {
    fn follow(&self, out: impl std::io::Read + Send + 'static) {
        let log = self.0.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if let Ok(v) = serde_json::from_str::<Value>(&line) {
                    log.lock().unwrap().push(v);
                }
            }
        });
    }

    pub fn all(&self, kind: &str) -> Vec<Value> {
        self.0.lock().unwrap().iter().filter_map(|v| v.get(kind).cloned()).collect()
    }

    /// Commands received: (header stamp, receipt on the robot's clock, linear, angular).
    pub fn commands(&self) -> Vec<Cmd> {
        self.all("cmd")
            .iter()
            .map(|c| Cmd {
                stamp: c["stamp"].as_f64().unwrap_or(f64::NAN),
                recv: c["recv"].as_f64().unwrap_or(f64::NAN),
                linear: c["linear"].as_f64().unwrap_or(f64::NAN),
                angular: c["angular"].as_f64().unwrap_or(f64::NAN),
            })
            .collect()
    }

    /// The newest odometry's x, m (0 before any).
    pub fn odom_x(&self) -> f64 {
        self.all("odom").last().and_then(|o| o["x"].as_f64()).unwrap_or(0.0)
    }
}

/// One `cmd_vel` message the robot received.
#[derive(Clone, Copy, Debug)]
pub struct Cmd {
    /// Its header stamp, s.
    pub stamp: f64,
    /// The robot's clock when it arrived, s.
    pub recv: f64,
    /// m/s.
    pub linear: f64,
    /// rad/s.
    pub angular: f64,
}

impl Cmd {
    pub fn moves(&self) -> bool {
        self.linear != 0.0 || self.angular != 0.0
    }
}
