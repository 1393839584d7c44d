//! README.md's "Connecting a real robot", word for word: every command of
//! its `<!-- doc-test: robot -->` block runs, in order, as a reader runs
//! them, with the fake Husky A300 of `tests/tests/ros2_robot.rs` (the real
//! rclpy of ROS 2 Jazzy on Fast DDS) standing in for the robot:
//!
//! - on "the gateway's computer" (a directory of its own, with the
//!   repository's models): `vlnav up --no-robot --listen 0.0.0.0:50051
//!   --gateway-name "$GATEWAY_HOST"` and `vlnav credentials robot`, with
//!   `GATEWAY_HOST` a second loopback address, 127.0.0.2, which the
//!   development certificate names only because of `--gateway-name`;
//! - the robot's files copied to "the robot's computer" (another
//!   directory), where `vlnav-edge --driver ros2` dials the gateway at that
//!   address over mutual TLS with them;
//! - back on the gateway's computer, grpcurl's ListRobots shows the robot
//!   attached, and `vlnav mission` drives it: it exits 0 (the mission
//!   succeeded) and the robot's own odometry moved about as far as asked.
//!
//! Also: the gateway's certificate is refused for an address it does not
//! name (127.0.0.3), and `vlnav credentials robot` prints the TLS flags the
//! README's `vlnav-edge` command uses.
//!
//! It runs in a user and network namespace of its own with only loopback
//! (`vlnav_e2e::ros2`): DDS stays on this machine, and every port `vlnav up`
//! wants by default (50051–50058, 4317, 8765) is free.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use vlnav_e2e::procs::binaries;
use vlnav_e2e::ros2::{FakeA300, Proc, inside_own_network_namespace, spawn};
use vlnav_e2e::{reader_shell, repo_root, tool};

const TEST: &str = "the_readme_connects_a_ros2_robot_over_tls_by_a_second_address";
const SECTION: &str = "## Connecting a real robot";
const MARKER: &str = "<!-- doc-test: robot -->";
/// The address the robot dials the gateway at: not one the development
/// certificate names by itself.
const GATEWAY_HOST: &str = "127.0.0.2";
/// An address the gateway listens on too (0.0.0.0) but that no certificate names.
const UNNAMED_HOST: &str = "127.0.0.3";
const ROBOT: &str = "husky-1";
const NAMESPACE: &str = "a300_0001";
const DOMAIN_ID: u32 = 23;

/// The commands of the README section's marked blocks, in order, each with
/// its `\` continuations joined. Every code block of the section must be
/// marked: a command this test does not run must not be in it.
fn section_commands() -> Vec<String> {
    let readme = std::fs::read_to_string(repo_root().join("README.md")).expect("README.md");
    let start = readme.find(&format!("\n{SECTION}\n")).unwrap_or_else(|| panic!("README.md has no {SECTION:?}"));
    let section = &readme[start + 1..];
    let section = &section[..section[SECTION.len()..].find("\n## ").map_or(section.len(), |i| i + SECTION.len())];
    let lines: Vec<&str> = section.lines().collect();
    let mut commands = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        if !lines[i].starts_with("```") {
            i += 1;
            continue;
        }
        assert!(
            i > 0 && lines[i - 1].trim() == MARKER,
            "README.md {SECTION:?}: every code block is run by tests/tests/real_robot.rs; mark it {MARKER}"
        );
        let end = (i + 1..lines.len()).find(|&j| lines[j].starts_with("```")).expect("the fence closes");
        let mut pending = String::new();
        for line in &lines[i + 1..end] {
            let t = line.trim();
            if pending.is_empty() && (t.is_empty() || t.starts_with('#')) {
                continue;
            }
            match t.strip_suffix('\\') {
                Some(head) => {
                    pending.push_str(head.trim_end());
                    pending.push(' ');
                }
                None => {
                    pending.push_str(t);
                    commands.push(std::mem::take(&mut pending));
                }
            }
        }
        i = end + 1;
    }
    commands
}

/// A reader's shell on one of the two computers: the deployment's
/// binaries and grpcurl on PATH, none of this machine's `VLNAV_*`
/// variables, `GATEWAY_HOST` set as the README asks.
fn shell(dir: &Path, line: &str, bin: &Path) -> Command {
    let mut cmd = reader_shell(line, dir, bin);
    cmd.env("GATEWAY_HOST", GATEWAY_HOST).env("ROS_DOMAIN_ID", DOMAIN_ID.to_string()).env("RUST_LOG", "warn");
    cmd
}

/// Runs a command to its end (at most `limit`); returns its output.
fn run(what: &str, mut cmd: Command, limit: Duration) -> Output {
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run `{what}`: {e}"));
    let start = Instant::now();
    while child.try_wait().expect("wait").is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            let out = child.wait_with_output().expect("output");
            panic!(
                "`{what}` did not finish within {} s:\n{}{}",
                limit.as_secs(),
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    child.wait_with_output().expect("output")
}

fn text(out: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

/// Polls `f` every 0.5 s until it gives a value; panics with the last
/// thing it said after `limit`.
fn poll<T>(what: &str, limit: Duration, mut f: impl FnMut() -> Result<T, String>) -> T {
    let start = Instant::now();
    loop {
        match f() {
            Ok(v) => return v,
            Err(last) => assert!(start.elapsed() < limit, "{what}: not within {} s; last:\n{last}", limit.as_secs()),
        }
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// The value of `--flag` in a command line.
fn flag<'a>(line: &'a str, name: &str) -> Option<&'a str> {
    let words: Vec<&str> = line.split_whitespace().collect();
    words.windows(2).find(|w| w[0] == name).map(|w| w[1])
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, to.join(p.file_name().unwrap())).unwrap();
    }
}

#[test]
fn the_readme_connects_a_ros2_robot_over_tls_by_a_second_address() {
    if inside_own_network_namespace(TEST) {
        inside_the_namespace();
    }
}

fn inside_the_namespace() {
    let commands = section_commands();
    assert!(commands.len() >= 4, "README.md {SECTION:?} has too few commands: {commands:?}");
    let bin: PathBuf = binaries().expect("the binaries were built outside");
    let gateway_pc = tempfile::tempdir().unwrap();
    let robot_pc = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink(repo_root().join("models"), gateway_pc.path().join("models")).unwrap();
    assert!(gateway_pc.path().join("models/minilm").exists(), "models are missing: run deploy/fetch-models.sh");

    // The robot, powered on: the fake A300 on its DDS domain.
    let a300 = FakeA300::start(NAMESPACE, 12.0, DOMAIN_ID);
    let log = a300.log.clone();

    let mut running: Vec<Proc> = Vec::new();
    let mut edge_flags = None;
    let mut attached = false;
    for line in &commands {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["vlnav", "up", ..] => {
                assert!(line.contains("--gateway-name \"$GATEWAY_HOST\""), "{line}");
                let mut up = shell(gateway_pc.path(), &format!("exec {line}"), &bin);
                up.stdout(Stdio::null()).stderr(Stdio::inherit());
                running.push(spawn(line, up));
                let token = gateway_pc.path().join(".vlnav/security/operator.token");
                poll("vlnav up listens and has written its credentials", Duration::from_secs(120), || {
                    let up = token.exists() && std::net::TcpStream::connect((GATEWAY_HOST, 50051)).is_ok();
                    up.then_some(()).ok_or_else(|| "not yet".to_string())
                });
                // An address the gateway answers on but its certificate does not name is refused.
                let ca = gateway_pc.path().join(".vlnav/security/ca.pem");
                let mut grpcurl = Command::new(tool("grpcurl"));
                grpcurl.arg("-cacert").arg(&ca).args([&format!("{UNNAMED_HOST}:50051"), "list"]);
                let out = run("grpcurl to an unnamed address", grpcurl, Duration::from_secs(30));
                assert!(!out.status.success(), "a certificate for {UNNAMED_HOST} that nobody asked for");
                assert!(text(&out).contains(&format!("not {UNNAMED_HOST}")), "{}", text(&out));
            }
            ["vlnav", "credentials", "robot", ..] => {
                let out = run(line, shell(gateway_pc.path(), line, &bin), Duration::from_secs(30));
                assert!(out.status.success(), "`{line}` failed:\n{}", text(&out));
                let printed = text(&out);
                assert!(!printed.contains("warning"), "{printed}");
                // The robot's files go to the robot's computer.
                let dir = flag(line, "--out").expect("the README names the directory to copy");
                copy_dir(&gateway_pc.path().join(dir), &robot_pc.path().join(dir));
                edge_flags = Some(printed);
            }
            ["vlnav-edge", ..] => {
                assert_eq!(flag(line, "--ros-namespace"), Some(NAMESPACE), "{line}");
                assert_eq!(flag(line, "--robot-id"), Some(ROBOT), "{line}");
                let printed = edge_flags.as_deref().expect("`vlnav credentials robot` runs before vlnav-edge");
                for f in ["--tls-ca", "--tls-client-cert", "--tls-client-key"] {
                    let want = format!("{f} {}", flag(line, f).unwrap_or_else(|| panic!("{line} has no {f}")));
                    assert!(printed.contains(&want), "`vlnav credentials robot` printed no `{want}`:\n{printed}");
                }
                let mut edge = shell(robot_pc.path(), &format!("exec {line}"), &bin);
                edge.stdout(Stdio::null()).stderr(Stdio::inherit());
                running.push(spawn(line, edge));
            }
            ["grpcurl", .., "vlnav.v1.FleetService/ListRobots"] => {
                let robot = poll("ListRobots shows the robot attached", Duration::from_secs(60), || {
                    let out = run(line, shell(gateway_pc.path(), line, &bin), Duration::from_secs(30));
                    if !out.status.success() {
                        return Err(text(&out));
                    }
                    let reply: Value =
                        serde_json::from_slice(&out.stdout).map_err(|e| format!("{e}: {}", text(&out)))?;
                    let robots = reply["robots"].as_array().cloned().unwrap_or_default();
                    robots
                        .into_iter()
                        .find(|r| r["robotId"] == ROBOT && r["connected"] == true && r["framesReceived"] != Value::Null)
                        .ok_or_else(|| text(&out))
                });
                assert_eq!(robot["driver"], "ros2", "{robot}");
                attached = true;
            }
            ["vlnav", "mission", ..] => {
                assert!(attached, "the README shows the robot attached before a mission");
                let asked: f64 = line
                    .split_whitespace()
                    .skip_while(|w| *w != "\"move")
                    .nth(1)
                    .and_then(|m| m.parse().ok())
                    .expect("the README's mission moves a distance: \"move N m ahead\"");
                let x0 = log.odom_x();
                let out = run(line, shell(gateway_pc.path(), line, &bin), Duration::from_secs(240));
                assert!(out.status.success(), "`{line}` did not succeed:\n{}", text(&out));
                let moved = log.odom_x() - x0;
                eprintln!("the README's mission: the robot's odometry moved {moved:.2} m for {asked} m asked");
                assert!((moved - asked).abs() < 0.5, "the robot moved {moved:.2} m for {asked} m:\n{}", text(&out));
                assert!(log.commands().iter().any(|c| c.linear > 0.0), "TwistStamped forward on its cmd_vel");
            }
            _ => panic!(
                "README.md {SECTION:?} has a command this test does not know how to run: {line}\nteach tests/tests/real_robot.rs"
            ),
        }
    }
    assert!(attached, "the README shows how to see the robot attached (ListRobots)");
    drop(running);
    drop(a300);
}
