//! The `sim` driver's session loops.
//!
//! Lockstep: render frame k, send it, wait for the one command that answers
//! it, apply that (through the governor) for one frame period, advance —
//! deterministic and as fast as the gateway answers. A wall-clock liveness
//! timeout only notices a dead gateway. When the gateway says `idle`, frames
//! are paced at real time so an idle robot does not spin the CPU.
//!
//! Real time: a wall-clock timer steps the world one frame period at a time;
//! commands are applied as they arrive, and the deadman stops the robot when
//! they stop.

use std::time::Duration;

use tokio::time::Instant;
use vlnav_geometry::convert::pose_to_proto;
use vlnav_proto::v1 as pb;
use vlnav_runtime::CancellationToken;
use vlnav_sim::{Simulator, Twist, load_scenario};

use crate::convert::{self, FrameMeta, RobotDescription};
use crate::link::{LastCommand, Link, SessionEnd, StatusReporter};
use crate::safety::{Backoff, Governor, Limits, Verdict};
use crate::{EdgeOptions, Hooks, LinkEvent, StepRecord};

pub(crate) fn limits_of(p: &vlnav_sim::HuskyParams) -> Limits {
    Limits {
        max_linear: p.max_linear,
        max_angular: p.max_angular,
        max_linear_accel: p.max_linear_accel,
        max_angular_accel: p.max_angular_accel,
    }
}

/// What a session drives: a world that gives the next frame and moves the
/// robot by a command for one frame period. The simulator renders each
/// frame ([`SimRobot`]); a replay sends recorded frames again
/// (`crate::replay`).
pub(crate) trait World {
    /// The next frame and the odometry at it.
    fn capture(&mut self) -> (pb::SensorFrame, pb::OdometryUpdate);
    /// Applies `cmd` for one frame period.
    fn step(&mut self, cmd: Twist);
    /// Sensor time, seconds.
    fn time(&self) -> f64;
    /// One frame period, seconds.
    fn period(&self) -> f64;
    /// Frames captured so far.
    fn frames(&self) -> u64;
    fn reset_odometry(&mut self);
    fn odometry(&self) -> vlnav_sim::Pose2;
    /// Ground truth, where the world knows it.
    fn truth(&self) -> Option<vlnav_sim::Truth>;
    /// `--max-sim-time-s` reached.
    fn time_is_up(&self) -> bool;
}

struct SimRobot {
    sim: Simulator,
    frame: vlnav_sim::Frame,
    camera: pb::CameraInfo,
    period: f64,
    seq: u64,
    robot_id: String,
    max_time: Option<f64>,
    codecs: crate::Codecs,
}

impl World for SimRobot {
    fn capture(&mut self) -> (pb::SensorFrame, pb::OdometryUpdate) {
        self.sim.render_into(&mut self.frame);
        let truth = self.sim.truth();
        let odom = self.sim.odometry();
        let stamp = self.sim.time();
        let wheel = odom.twist;
        let meta = FrameMeta {
            robot_id: &self.robot_id,
            seq: self.seq,
            stamp,
            camera: self.camera,
            odom: odom.pose,
            odom_twist: wheel,
            codecs: self.codecs,
        };
        let frame = pb::SensorFrame {
            frame: Some(convert::sim_frame(meta, &self.frame)),
            truth: Some(convert::sim_truth(&truth)),
        };
        let odo =
            pb::OdometryUpdate { stamp, pose: Some(pose_to_proto(&odom.pose)), twist: Some(convert::twist(&wheel)) };
        self.seq += 1;
        (frame, odo)
    }

    fn step(&mut self, cmd: Twist) {
        self.sim.step(cmd, self.period);
    }

    fn time(&self) -> f64 {
        self.sim.time()
    }

    fn period(&self) -> f64 {
        self.period
    }

    fn frames(&self) -> u64 {
        self.seq
    }

    fn reset_odometry(&mut self) {
        self.sim.reset_odometry()
    }

    fn odometry(&self) -> vlnav_sim::Pose2 {
        self.sim.odometry().pose
    }

    fn truth(&self) -> Option<vlnav_sim::Truth> {
        Some(self.sim.truth())
    }

    fn time_is_up(&self) -> bool {
        self.max_time.is_some_and(|m| self.sim.time() >= m - 1e-9)
    }
}

/// Runs the `sim` driver: reconnects with backoff, holding the robot stopped.
pub async fn run_sim(opts: &EdgeOptions, shutdown: CancellationToken, hooks: Hooks) -> anyhow::Result<()> {
    let world = load_scenario(&opts.scenario).map_err(|e| anyhow::anyhow!("scenario `{}`: {e}", opts.scenario))?;
    let mut sim = Simulator::new(world, opts.seed);
    if opts.width.is_some() || opts.height.is_some() {
        let cam = sim.camera().clone();
        let (w, h) = (opts.width.unwrap_or(cam.width), opts.height.unwrap_or(cam.height));
        sim.set_camera(cam.with_resolution(w, h).map_err(|e| anyhow::anyhow!("--width/--height: {e}"))?);
    }
    let params = *sim.params();
    let desc =
        RobotDescription { limits: limits_of(&params), footprint_length: params.length, footprint_width: params.width };
    let camera = convert::sim_camera_info(sim.camera());
    let hello = pb::EdgeHello {
        robot_id: opts.robot_id.clone(),
        driver: "sim".into(),
        limits: Some(convert::limits(&desc)),
        camera: Some(camera),
        lockstep: opts.lockstep,
    };
    let mut robot = SimRobot {
        sim,
        frame: Default::default(),
        camera,
        period: 1.0 / opts.frame_rate,
        seq: 0,
        robot_id: opts.robot_id.clone(),
        max_time: opts.max_sim_time_s,
        codecs: opts.codecs(),
    };
    tracing::info!(robot = %opts.robot_id, scenario = %opts.scenario, lockstep = opts.lockstep, gateway = %opts.gateway, "sim edge agent starting");
    drive(opts, &mut robot, hello, desc.limits, shutdown, hooks).await
}

/// Drives `robot` through the gateway until the run ends: attaches,
/// reconnects with backoff when the link is lost, and holds the robot
/// stopped while it is down.
pub(crate) async fn drive(
    opts: &EdgeOptions,
    robot: &mut impl World,
    hello: pb::EdgeHello,
    limits: Limits,
    shutdown: CancellationToken,
    hooks: Hooks,
) -> anyhow::Result<()> {
    let mut gov = Governor::new(limits, opts.deadman_timeout_s);
    let mut backoff =
        Backoff::new(Duration::from_secs_f64(opts.reconnect_initial_s), Duration::from_secs_f64(opts.reconnect_max_s));
    let mut status = StatusReporter::default();
    loop {
        if shutdown.is_cancelled() || robot.time_is_up() {
            return Ok(());
        }
        let connected = tokio::select! {
            _ = shutdown.cancelled() => return Ok(()),
            r = Link::connect(opts, hello.clone()) => r,
        };
        let end = match connected {
            Ok(mut link) => {
                backoff.reset();
                status.reset();
                tracing::info!(robot = %opts.robot_id, "attached to the gateway");
                let mut session = Session {
                    opts,
                    robot: &mut *robot,
                    gov: &mut gov,
                    link: &mut link,
                    status: &mut status,
                    hooks: &hooks,
                    shutdown: &shutdown,
                };
                if opts.lockstep { session.lockstep().await } else { session.realtime().await }
            }
            Err(e) => SessionEnd::Lost(format!("{e:#}")),
        };
        match end {
            SessionEnd::Finished => return Ok(()),
            SessionEnd::Lost(reason) => {
                gov.drop_command();
                let delay = backoff.next_delay();
                tracing::warn!(robot = %opts.robot_id, %reason, retry_in_s = delay.as_secs_f64(), "gateway link down; robot held stopped");
                if hold_stopped(opts, robot, &mut gov, &hooks, delay, &shutdown).await {
                    return Ok(());
                }
            }
        }
    }
}

/// Waits `delay` with the robot stopped. In real time the world keeps
/// moving (pedestrians walk, the robot brakes); in lockstep it is frozen.
/// Returns true when the run should end.
async fn hold_stopped(
    opts: &EdgeOptions,
    robot: &mut impl World,
    gov: &mut Governor,
    hooks: &Hooks,
    delay: Duration,
    shutdown: &CancellationToken,
) -> bool {
    let until = Instant::now() + delay;
    if opts.lockstep {
        tokio::select! {
            _ = shutdown.cancelled() => return true,
            _ = tokio::time::sleep_until(until) => return false,
        }
    }
    let mut tick = tokio::time::interval(Duration::from_secs_f64(robot.period()));
    loop {
        tokio::select! {
            _ = shutdown.cancelled() => return true,
            _ = tokio::time::sleep_until(until) => return false,
            _ = tick.tick() => {
                gov.set_estop(hooks.estop.is_engaged());
                let (out, verdict) = gov.output(robot.time());
                robot.step(out);
                observe(hooks, robot, out, verdict, gov, false, String::new());
                if robot.time_is_up() { return true; }
            }
        }
    }
}

fn timing(hooks: &Hooks, event: LinkEvent) {
    if let Some(t) = &hooks.timing {
        let _ = t.send(event);
    }
}

fn observe(
    hooks: &Hooks,
    robot: &impl World,
    applied: Twist,
    verdict: Verdict,
    gov: &Governor,
    idle: bool,
    mission_id: String,
) {
    if let Some(obs) = &hooks.observer {
        let _ = obs.send(StepRecord {
            seq: robot.frames().saturating_sub(1),
            stamp: robot.time(),
            odom: robot.odometry(),
            truth: robot.truth(),
            command: gov.command(),
            applied,
            verdict,
            idle,
            mission_id,
        });
    }
}

/// One connection's worth of driving the simulated robot: what a session
/// reads, and the state it carries over to the next connection.
struct Session<'a, W: World> {
    opts: &'a EdgeOptions,
    robot: &'a mut W,
    gov: &'a mut Governor,
    link: &'a mut Link,
    status: &'a mut StatusReporter,
    hooks: &'a Hooks,
    shutdown: &'a CancellationToken,
}

impl<W: World> Session<'_, W> {
    /// One frame out, one command back, then the next frame.
    async fn lockstep(&mut self) -> SessionEnd {
        let Session { opts, robot, gov, link, status, hooks, shutdown } = self;
        let (opts, hooks, shutdown) = (*opts, *hooks, *shutdown);
        let liveness = Duration::from_secs_f64(opts.liveness_timeout_s);
        let mut last = LastCommand::new(gov);
        loop {
            if shutdown.is_cancelled() || robot.time_is_up() {
                return SessionEnd::Finished;
            }
            let (frame, odo) = robot.capture();
            let stamp = robot.time();
            for msg in [
                convert::edge(pb::edge_message::Kind::Odometry(odo)),
                convert::edge(pb::edge_message::Kind::Frame(frame)),
            ] {
                tokio::select! {
                    _ = shutdown.cancelled() => return SessionEnd::Finished,
                    r = link.send(msg) => if let Err(e) = r { return SessionEnd::Lost(e) },
                }
            }
            last.frame_sent(stamp);
            // The one command that answers this frame.
            let deadline = Instant::now() + liveness;
            let answer = loop {
                let msg = tokio::select! {
                    _ = shutdown.cancelled() => return SessionEnd::Finished,
                    _ = tokio::time::sleep_until(deadline) => {
                        return SessionEnd::Lost(format!("no command for the frame stamped {stamp:.3} s within {} s", opts.liveness_timeout_s));
                    }
                    m = link.recv() => m,
                };
                match msg {
                    Err(e) => return SessionEnd::Lost(e),
                    Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::Velocity(v)) }) => break v,
                    Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::ResetOdometry(_)) }) => {
                        robot.reset_odometry()
                    }
                    Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::Mission(a)) }) => last.announce(&a),
                    Ok(_) => {}
                }
            };
            // Free: the gateway says no mission drives this robot. Read off the
            // answer as it came, dropped or not, so that time passes while
            // commands are refused (the deadman must be able to trip).
            let free = answer.idle && answer.mission_id.is_empty() && hooks.idle_gate.is_none();
            last.take(gov, answer);
            gov.set_estop(hooks.estop.is_engaged());
            let (out, verdict) = gov.output(stamp);
            if let Some(s) = status.update(stamp, verdict)
                && let Err(e) = link.send(s).await
            {
                return SessionEnd::Lost(e);
            }
            observe(hooks, &**robot, out, verdict, gov, last.idle, last.mission.clone());
            // A lockstep world moves only while a mission drives the robot:
            // free, the robot keeps sending frames of a world standing still
            // (its clock too), so a mission starts from the same state
            // however long after attaching it was submitted (a pedestrian
            // who walked on while the robot waited changed Case 2's course in
            // the demo hall). A harness that holds the robot at an idle gate
            // chooses that frame itself.
            if !free {
                robot.step(out);
            }
            if last.idle {
                match &hooks.idle_gate {
                    Some(gate) if !gate.is_open() => tokio::select! {
                        _ = shutdown.cancelled() => return SessionEnd::Finished,
                        _ = gate.opened() => {}
                    },
                    _ => tokio::select! {
                        _ = shutdown.cancelled() => return SessionEnd::Finished,
                        _ = tokio::time::sleep(Duration::from_secs_f64(robot.period())) => {}
                    },
                }
            }
        }
    }

    /// Frames at the frame rate; commands apply whenever they arrive.
    async fn realtime(&mut self) -> SessionEnd {
        let Session { opts, robot, gov, link, status, hooks, shutdown } = self;
        let (opts, hooks, shutdown) = (*opts, *hooks, *shutdown);
        let liveness = Duration::from_secs_f64(opts.liveness_timeout_s);
        let mut tick = tokio::time::interval(Duration::from_secs_f64(robot.period()));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut last = LastCommand::new(gov);
        // The first frame goes out at once; then one per tick, after stepping.
        let mut first = true;
        loop {
            tokio::select! {
                _ = shutdown.cancelled() => return SessionEnd::Finished,
                m = link.recv() => match m {
                    Err(e) => return SessionEnd::Lost(e),
                    Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::Velocity(v)) }) => {
                        timing(hooks, LinkEvent::Command { stamp: v.stamp, idle: v.idle, at: std::time::Instant::now() });
                        last.take(gov, v)
                    }
                    Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::ResetOdometry(_)) }) => robot.reset_odometry(),
                    Ok(pb::GatewayCommand { kind: Some(pb::gateway_command::Kind::Mission(a)) }) => last.announce(&a),
                    Ok(_) => {}
                },
                _ = tick.tick() => {
                    if link.last_heard().elapsed() > liveness {
                        return SessionEnd::Lost(format!("nothing from the gateway for {} s", opts.liveness_timeout_s));
                    }
                    if !first {
                        gov.set_estop(hooks.estop.is_engaged());
                        let (out, verdict) = gov.output(robot.time());
                        if let Some(s) = status.update(robot.time(), verdict) && let Err(e) = link.offer(s) {
                            return SessionEnd::Lost(e);
                        }
                        observe(hooks, &**robot, out, verdict, gov, last.idle, last.mission.clone());
                        robot.step(out);
                    }
                    first = false;
                    if robot.time_is_up() {
                        return SessionEnd::Finished;
                    }
                    let (frame, odo) = robot.capture();
                    let stamp = frame.frame.as_ref().map(|f| f.stamp);
                    let image_bytes = frame.frame.as_ref().map_or(0, convert::image_bytes);
                    let bytes = prost::Message::encoded_len(&frame);
                    let mut queued = true;
                    for msg in [convert::edge(pb::edge_message::Kind::Odometry(odo)), convert::edge(pb::edge_message::Kind::Frame(frame))] {
                        match link.offer(msg) {
                            Ok(q) => queued = q,
                            Err(e) => return SessionEnd::Lost(e),
                        }
                    }
                    if let Some(stamp) = stamp {
                        last.frame_sent(stamp);
                        timing(hooks, LinkEvent::Frame { stamp, queued, at: std::time::Instant::now(), bytes, image_bytes });
                    }
                }
            }
        }
    }
}
