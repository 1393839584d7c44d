//! What the robot saw, live and recorded (docs/observability.md).
//!
//! One thread owns a Foxglove [`Context`]; every robot has its topics on it
//! under `/<robot_id>/…`, in Foxglove's well-known schemas where one fits and
//! in vlnav's own protobuf messages (`proto/vlnav/v1`) otherwise. Two kinds of
//! sink read them:
//!
//! - the live view, a Foxglove WebSocket server (Foxglove, Lichtblick);
//! - one MCAP writer per running mission, filtered to its robot's topics,
//!   chunked and zstd-compressed, continued in a new file past a size limit.
//!
//! The robot actors hand their frames over after the velocity command has
//! left; at most [`MAX_QUEUED_FRAMES`] wait here. Beyond that a real-time
//! robot's frame is dropped and counted (and said in the log), so its control
//! loop never waits; a lockstep robot's waits for a place, since its clock
//! stands still until answered. Nothing is encoded for a topic nobody reads.

use std::collections::HashMap;
use std::io::BufWriter;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;

use foxglove::messages as fg;
use foxglove::{Channel, Context, McapWriterHandle, PartialMetadata, RawChannel, Schema};
use prost::Message;
use vlnav_proto::v1 as pb;

use crate::config::ViewOptions;
use crate::executor::Seen;
use crate::hub::Hub;

/// Frames waiting for the view thread beyond which a newer one is dropped.
pub(crate) const MAX_QUEUED_FRAMES: usize = 8;
/// Frames between two checks of a recording's size.
const SIZE_CHECK_EVERY: u64 = 25;

/// The mission a frame belongs to, as the live view shows it.
#[derive(Clone, Debug, Default)]
pub(crate) struct MissionView {
    pub(crate) mission_id: String,
    /// The step under way: index and description.
    pub(crate) step: Option<(u32, String)>,
    pub(crate) steps: usize,
    /// "running", "awaiting answer", or the terminal state it reached.
    pub(crate) state: String,
}

/// The robot's own state when a frame arrived, as its edge agent last
/// reported it (`RobotStatus` in proto/vlnav/v1/fleet.proto).
#[derive(Clone, Debug, Default)]
pub(crate) struct RobotHealth {
    /// Any e-stop engaged: the edge agent's or the robot's own.
    pub(crate) estop: bool,
    /// The robot's own emergency stop is engaged.
    pub(crate) platform_estop: bool,
    /// `None` while the robot reports no battery.
    pub(crate) battery: Option<pb::BatteryStatus>,
}

/// One frame and what the gateway made of it.
pub(crate) struct FrameView {
    pub(crate) robot_id: String,
    pub(crate) frame: pb::SensorFrame,
    pub(crate) command: pb::VelocityCommand,
    pub(crate) mission: Option<MissionView>,
    pub(crate) seen: Seen,
    pub(crate) health: RobotHealth,
}

enum Msg {
    /// The permit is the frame's place in the queue, given back once drawn.
    Frame(Box<FrameView>, tokio::sync::OwnedSemaphorePermit),
    Start {
        robot_id: String,
        mission_id: String,
        path: PathBuf,
        plan: pb::ActionPlan,
        instruction: String,
    },
    Event {
        robot_id: String,
        event: pb::MissionEvent,
    },
    End {
        robot_id: String,
        mission_id: String,
    },
    Flush(mpsc::Sender<()>),
    /// Ends every recording (the gateway is closing).
    Finish(mpsc::Sender<()>),
}

/// The handle robot actors use; cheap to clone. Without a live view and
/// without recordings every call returns at once.
#[derive(Clone, Default)]
pub(crate) struct Viz {
    inner: Option<Arc<Inner>>,
}

struct Inner {
    tx: mpsc::Sender<Msg>,
    /// Places for frames waiting for the view thread.
    places: Arc<tokio::sync::Semaphore>,
    dropped: AtomicU64,
    live: Option<SocketAddr>,
    record_dir: Option<PathBuf>,
}

impl Viz {
    /// Starts the view thread (and the live view's server, bound before this
    /// returns so a taken port is an error here) when either is wanted.
    pub(crate) fn start(opts: &ViewOptions, data_dir: &Path, hub: Arc<Hub>) -> anyhow::Result<Self> {
        let live = opts.live_addr()?;
        if live.is_none() && !opts.record {
            return Ok(Self::default());
        }
        let record_dir = opts.record.then(|| data_dir.join("recordings"));
        if let Some(dir) = &record_dir {
            std::fs::create_dir_all(dir)
                .map_err(|e| anyhow::anyhow!("cannot create the recordings directory {}: {e}", dir.display()))?;
        }
        let (tx, rx) = mpsc::channel();
        let (ready_tx, ready_rx) = mpsc::channel();
        let places = Arc::new(tokio::sync::Semaphore::new(MAX_QUEUED_FRAMES));
        let max_bytes = opts.record_max_mib.saturating_mul(1 << 20);
        let metadata = opts.metadata.clone();
        let budget = opts.record_budget_mib.saturating_mul(1 << 20);
        std::thread::Builder::new().name("vlnav-view".into()).spawn(move || {
            let ctx = Context::new();
            let server = match live {
                Some(addr) => {
                    let started = foxglove::WebSocketServer::new()
                        .name("vlnav")
                        .context(&ctx)
                        .bind(addr.ip().to_string(), addr.port())
                        .start_blocking();
                    match started {
                        Ok(server) => {
                            let _ = ready_tx.send(Ok(Some(SocketAddr::new(addr.ip(), server.port()))));
                            Some(server)
                        }
                        Err(e) => {
                            let _ = ready_tx.send(Err(anyhow::anyhow!(
                                "cannot serve the live view on {addr}: {e}; pick another with --live-view ADDR, or `off`"
                            )));
                            return;
                        }
                    }
                }
                None => {
                    let _ = ready_tx.send(Ok(None));
                    None
                }
            };
            let mut view = View { ctx, hub, max_bytes, budget, metadata, robots: HashMap::new() };
            while let Ok(msg) = rx.recv() {
                view.handle(msg);
            }
            // The gateway is closing: finish every recording's file.
            view.robots.clear();
            if let Some(server) = server {
                server.stop().wait_blocking();
            }
        })?;
        let live = ready_rx.recv().map_err(|_| anyhow::anyhow!("the live view's thread ended before it started"))??;
        if let Some(addr) = live {
            tracing::info!(%addr, "live view (Foxglove WebSocket) at ws://{addr}");
        }
        Ok(Self { inner: Some(Arc::new(Inner { tx, places, dropped: AtomicU64::new(0), live, record_dir })) })
    }

    /// Where the live view listens (with the port the OS chose for port 0).
    pub(crate) fn live_addr(&self) -> Option<SocketAddr> {
        self.inner.as_ref().and_then(|i| i.live)
    }

    /// Frames dropped because the view thread was behind.
    #[cfg(test)]
    pub(crate) fn dropped_frames(&self) -> u64 {
        self.inner.as_ref().map_or(0, |i| i.dropped.load(Ordering::Relaxed))
    }

    /// Starts recording a mission; returns the file it goes to. The mission
    /// record names it once the file is open.
    pub(crate) fn start_mission(
        &self,
        robot_id: &str,
        mission_id: &str,
        plan: pb::ActionPlan,
        instruction: &str,
    ) -> Option<PathBuf> {
        let inner = self.inner.as_ref()?;
        let path = inner.record_dir.as_ref()?.join(format!("{mission_id}.mcap"));
        let _ = inner.tx.send(Msg::Start {
            robot_id: robot_id.into(),
            mission_id: mission_id.into(),
            path: path.clone(),
            plan,
            instruction: instruction.into(),
        });
        Some(path)
    }

    /// Ends a mission's recording (its file is finished and closed).
    pub(crate) fn end_mission(&self, robot_id: &str, mission_id: &str) {
        if let Some(inner) = &self.inner {
            let _ = inner.tx.send(Msg::End { robot_id: robot_id.into(), mission_id: mission_id.into() });
        }
    }

    /// A mission event, in the recording and the live view.
    pub(crate) fn event(&self, robot_id: &str, event: pb::MissionEvent) {
        if let Some(inner) = &self.inner {
            let _ = inner.tx.send(Msg::Event { robot_id: robot_id.into(), event });
        }
    }

    /// Whether frames are wanted at all.
    pub(crate) fn is_on(&self) -> bool {
        self.inner.is_some()
    }

    /// A frame after its command left. When the view thread is
    /// [`MAX_QUEUED_FRAMES`] behind, a real-time robot's frame is dropped
    /// from the view and the recording (and counted): its control loop never
    /// waits. A lockstep robot's clock stands still until it is answered, so
    /// its frame waits for a place instead and its recording stays complete.
    pub(crate) async fn frame(&self, view: FrameView, lockstep: bool) {
        let Some(inner) = &self.inner else { return };
        let permit = match inner.places.clone().try_acquire_owned() {
            Ok(permit) => permit,
            Err(_) if lockstep => match inner.places.clone().acquire_owned().await {
                Ok(permit) => permit,
                Err(_) => return,
            },
            Err(_) => {
                let n = inner.dropped.fetch_add(1, Ordering::Relaxed) + 1;
                if n.is_power_of_two() {
                    tracing::warn!(
                        dropped = n,
                        "the live view and recordings are behind; frames are dropped from them"
                    );
                }
                return;
            }
        };
        let _ = inner.tx.send(Msg::Frame(Box::new(view), permit));
    }

    /// Waits until everything handed over so far is written (tests).
    pub(crate) fn flush(&self) {
        self.wait_for(Msg::Flush);
    }

    /// Writes what was handed over, then ends every recording still open, so
    /// that each file is complete (summary and footer) when the gateway stops.
    pub(crate) fn finish(&self) {
        self.wait_for(Msg::Finish);
    }

    fn wait_for(&self, msg: fn(mpsc::Sender<()>) -> Msg) {
        if let Some(inner) = &self.inner {
            let (tx, rx) = mpsc::channel();
            if inner.tx.send(msg(tx)).is_ok() {
                let _ = rx.recv_timeout(std::time::Duration::from_secs(30));
            }
        }
    }
}

/// The view thread's state.
struct View {
    ctx: Arc<Context>,
    hub: Arc<Hub>,
    max_bytes: u64,
    /// Size the recordings directory is kept under (0: unbounded).
    budget: u64,
    metadata: Vec<(String, String)>,
    robots: HashMap<String, RobotView>,
}

struct RobotView {
    topics: Topics,
    /// Odometry positions since the last re-anchoring (step start), odom.
    trail: Vec<[f64; 2]>,
    last_stamp: f64,
    recording: Option<Recording>,
}

struct Recording {
    mission_id: String,
    /// Path of the first file; later parts are `<id>.partN.mcap` beside it.
    first: PathBuf,
    current: PathBuf,
    part: u32,
    handle: Option<McapWriterHandle<BufWriter<std::fs::File>>>,
    frames: u64,
}

impl Drop for Recording {
    fn drop(&mut self) {
        if let Some(handle) = self.handle.take()
            && let Err(e) = handle.close()
        {
            tracing::error!(mission = %self.mission_id, "cannot finish the recording {}: {e}", self.current.display());
        }
    }
}

/// A robot's channels. Topic names are in docs/observability.md and the
/// committed layout `deploy/foxglove/vlnav-layout.json`.
struct Topics {
    robot: String,
    image: Channel<fg::CompressedImage>,
    annotations: Channel<fg::ImageAnnotations>,
    depth: Channel<fg::RawImage>,
    calibration: Channel<fg::CameraCalibration>,
    no_go: Channel<fg::PointCloud>,
    scene: Channel<fg::SceneUpdate>,
    tf: Channel<fg::FrameTransforms>,
    truth: Channel<fg::PoseInFrame>,
    command: Arc<RawChannel>,
    status: Arc<RawChannel>,
    events: Arc<RawChannel>,
    plan: Arc<RawChannel>,
    frames: Arc<RawChannel>,
}

/// The JSON schema of `/<robot>/mission/status`.
const STATUS_SCHEMA: &str = r#"{"title":"vlnav mission status","type":"object","properties":{
"mission_id":{"type":"string"},"state":{"type":"string"},"step":{"type":"integer"},"steps":{"type":"integer"},
"step_desc":{"type":"string"},"drive_status":{"type":"string"},"distance_to_goal_m":{"type":"number"},
"free_paths":{"type":"integer"},"boxes":{"type":"integer"},"linear_mps":{"type":"number"},
"angular_radps":{"type":"number"},"estop":{"type":"boolean"},"platform_estop":{"type":"boolean"},
"battery_fraction":{"type":"number"},"battery_voltage":{"type":"number"},"battery_low":{"type":"boolean"},
"stamp":{"type":"number"}}}"#;

impl Topics {
    fn new(ctx: &Arc<Context>, robot: &str) -> Self {
        let t = |name: &str| format!("/{robot}/{name}");
        let proto = |name: &str, message: &str| {
            ctx.channel_builder(t(name))
                .message_encoding("protobuf")
                .schema(Schema::new(message, "protobuf", vlnav_proto::FILE_DESCRIPTOR_SET))
                .build_raw()
                .expect("a protobuf channel with a static schema builds")
        };
        Self {
            robot: robot.to_string(),
            image: ctx.channel_builder(t("camera/image")).build(),
            annotations: ctx.channel_builder(t("camera/annotations")).build(),
            depth: ctx.channel_builder(t("camera/depth")).build(),
            calibration: ctx.channel_builder(t("camera/calibration")).build(),
            no_go: ctx.channel_builder(t("segmenter/no_go")).build(),
            scene: ctx.channel_builder(t("scene")).build(),
            tf: ctx.channel_builder(t("tf")).build(),
            truth: ctx.channel_builder(t("truth/pose")).build(),
            command: proto("cmd_vel", "vlnav.v1.VelocityCommand"),
            status: ctx
                .channel_builder(t("mission/status"))
                .message_encoding("json")
                .schema(Schema::new("vlnav.MissionStatus", "jsonschema", STATUS_SCHEMA.as_bytes()))
                .build_raw()
                .expect("a JSON channel with a static schema builds"),
            events: proto("mission/events", "vlnav.v1.MissionEvent"),
            plan: proto("mission/plan", "vlnav.v1.ActionPlan"),
            frames: proto("sensor_frame", "vlnav.v1.SensorFrame"),
        }
    }

    fn frame_id(&self, name: &str) -> String {
        format!("{}/{name}", self.robot)
    }
}

fn nanos(stamp: f64) -> u64 {
    (stamp.max(0.0) * 1e9).round() as u64
}

fn timestamp(stamp: f64) -> Option<fg::Timestamp> {
    let ns = nanos(stamp);
    Some(fg::Timestamp::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32))
}

fn color(r: f64, g: f64, b: f64, a: f64) -> Option<fg::Color> {
    Some(fg::Color { r, g, b, a })
}

fn yaw_quaternion(yaw: f64) -> Option<fg::Quaternion> {
    Some(fg::Quaternion { x: 0.0, y: 0.0, z: (yaw / 2.0).sin(), w: (yaw / 2.0).cos() })
}

/// Roll, pitch, yaw (REP-103, applied in z-y-x order) as a quaternion.
fn rpy_quaternion(roll: f64, pitch: f64, yaw: f64) -> Option<fg::Quaternion> {
    let q = nalgebra::UnitQuaternion::from_euler_angles(roll, pitch, yaw);
    Some(fg::Quaternion { x: q.i, y: q.j, z: q.k, w: q.w })
}

fn pose(x: f64, y: f64, z: f64, q: Option<fg::Quaternion>) -> Option<fg::Pose> {
    Some(fg::Pose { position: Some(fg::Vector3 { x, y, z }), orientation: q })
}

fn transform(stamp: f64, parent: String, child: String, t: [f64; 3], q: Option<fg::Quaternion>) -> fg::FrameTransform {
    fg::FrameTransform {
        timestamp: timestamp(stamp),
        parent_frame_id: parent,
        child_frame_id: child,
        translation: Some(fg::Vector3 { x: t[0], y: t[1], z: t[2] }),
        rotation: q,
    }
}

impl View {
    fn robot(&mut self, robot_id: &str) -> &mut RobotView {
        let ctx = &self.ctx;
        self.robots.entry(robot_id.to_string()).or_insert_with(|| RobotView {
            topics: Topics::new(ctx, robot_id),
            trail: Vec::new(),
            last_stamp: 0.0,
            recording: None,
        })
    }

    fn handle(&mut self, msg: Msg) {
        match msg {
            Msg::Frame(view, _place) => self.frame(*view),
            Msg::Start { robot_id, mission_id, path, plan, instruction } => {
                if self.budget > 0
                    && let Some(dir) = path.parent()
                {
                    let open: Vec<PathBuf> =
                        self.robots.values().filter_map(|r| r.recording.as_ref().map(|r| r.current.clone())).collect();
                    prune(dir, self.budget, &open);
                }
                let ctx = self.ctx.clone();
                let extra = self.metadata.clone();
                let robot = self.robot(&robot_id);
                robot.recording = None;
                robot.trail.clear();
                let recording = match open_part(&ctx, &robot_id, &path) {
                    Ok(handle) => Some(Recording {
                        mission_id: mission_id.clone(),
                        first: path.clone(),
                        current: path.clone(),
                        part: 1,
                        handle: Some(handle),
                        frames: 0,
                    }),
                    Err(e) => {
                        tracing::error!(mission = %mission_id, "cannot record the mission to {}: {e}", path.display());
                        None
                    }
                };
                let recorded = recording.as_ref().map(|r| r.first.display().to_string());
                robot.recording = recording;
                let stamp = robot.last_stamp;
                if let Some(handle) = robot.recording.as_ref().and_then(|r| r.handle.as_ref()) {
                    let mut meta = std::collections::BTreeMap::new();
                    meta.insert("mission_id".to_string(), mission_id.clone());
                    meta.insert("robot_id".to_string(), robot_id.clone());
                    meta.insert("instruction".to_string(), instruction);
                    meta.extend(extra);
                    if let Err(e) = handle.write_metadata("vlnav.mission", meta) {
                        tracing::warn!(mission = %mission_id, "cannot write the recording's metadata: {e}");
                    }
                }
                robot.topics.plan.log_with_meta(&plan.encode_to_vec(), PartialMetadata::with_log_time(nanos(stamp)));
                if let Some(file) = recorded
                    && let Err(e) = self.hub.record(&mission_id, stamp, None, |m| m.recordings = vec![file])
                {
                    tracing::warn!(mission = %mission_id, "cannot note the mission's recording: {e}");
                }
            }
            Msg::Event { robot_id, event } => {
                let robot = self.robot(&robot_id);
                if robot.topics.events.has_sinks() {
                    let at = nanos(event.stamp.max(robot.last_stamp));
                    robot.topics.events.log_with_meta(&event.encode_to_vec(), PartialMetadata::with_log_time(at));
                }
            }
            Msg::End { robot_id, mission_id } => {
                if let Some(robot) = self.robots.get_mut(&robot_id)
                    && robot.recording.as_ref().is_some_and(|r| r.mission_id == mission_id)
                {
                    robot.recording = None;
                }
            }
            Msg::Finish(done) => {
                for robot in self.robots.values_mut() {
                    robot.recording = None;
                }
                let _ = done.send(());
            }
            Msg::Flush(done) => {
                for robot in self.robots.values() {
                    if let Some(handle) = robot.recording.as_ref().and_then(|r| r.handle.as_ref()) {
                        let _ = handle.flush();
                    }
                }
                let _ = done.send(());
            }
        }
    }

    fn frame(&mut self, view: FrameView) {
        let FrameView { robot_id, mut frame, command, mission, seen, health } = view;
        let Some(mut f) = frame.frame.take() else { return };
        let truth = frame.truth;
        let (max_bytes, ctx, hub) = (self.max_bytes, self.ctx.clone(), self.hub.clone());
        let robot = self.robot(&robot_id);
        let stamp = f.stamp;
        robot.last_stamp = stamp;
        let t = &robot.topics;
        let at = || PartialMetadata::with_log_time(nanos(stamp));

        // The raw frame first, before its pixels are moved into the views below.
        if t.frames.has_sinks() {
            let raw = pb::SensorFrame { frame: Some(f.clone()), truth };
            t.frames.log_with_meta(&raw.encode_to_vec(), at());
        }
        if t.command.has_sinks() {
            t.command.log_with_meta(&command.encode_to_vec(), at());
        }

        let odom = f.odom.unwrap_or_default();
        if seen.step_started {
            robot.trail.clear();
        }
        if robot.trail.last().is_none_or(|p| (p[0] - odom.x).hypot(p[1] - odom.y) > 0.02) {
            robot.trail.push([odom.x, odom.y]);
        }

        if t.tf.has_sinks() {
            let mut transforms = vec![transform(
                stamp,
                t.frame_id("odom"),
                t.frame_id("base_link"),
                [odom.x, odom.y, 0.0],
                yaw_quaternion(odom.theta),
            )];
            if let Some(mount) = f.camera.as_ref().and_then(|c| c.mount.as_ref()) {
                let p = mount.translation.unwrap_or_default();
                transforms.push(transform(
                    stamp,
                    t.frame_id("base_link"),
                    t.frame_id("camera"),
                    [p.x, p.y, p.z],
                    rpy_quaternion(mount.roll, mount.pitch, mount.yaw),
                ));
                // REP-103 optical frame: z forward, x right, y down.
                transforms.push(transform(
                    stamp,
                    t.frame_id("camera"),
                    t.frame_id("camera_optical"),
                    [0.0; 3],
                    rpy_quaternion(-std::f64::consts::FRAC_PI_2, 0.0, -std::f64::consts::FRAC_PI_2),
                ));
            }
            if let Some(origin) = truth.as_ref().and_then(|t| t.odom_origin) {
                transforms.push(transform(
                    stamp,
                    t.frame_id("world"),
                    t.frame_id("odom"),
                    [origin.x, origin.y, 0.0],
                    yaw_quaternion(origin.theta),
                ));
            }
            t.tf.log_with_time(&fg::FrameTransforms { transforms }, nanos(stamp));
        }

        if let Some(p) = truth.as_ref().and_then(|t| t.pose)
            && t.truth.has_sinks()
        {
            t.truth.log_with_time(
                &fg::PoseInFrame {
                    timestamp: timestamp(stamp),
                    frame_id: t.frame_id("world"),
                    pose: pose(p.x, p.y, 0.0, yaw_quaternion(p.theta)),
                },
                nanos(stamp),
            );
        }

        if let Some(cam) = &f.camera
            && let Some(k) = &cam.intrinsics
            && t.calibration.has_sinks()
        {
            t.calibration.log_with_time(
                &fg::CameraCalibration {
                    timestamp: timestamp(stamp),
                    frame_id: t.frame_id("camera_optical"),
                    width: cam.width,
                    height: cam.height,
                    distortion_model: String::new(),
                    d: vec![],
                    k: vec![k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
                    r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                    p: vec![k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
                },
                nanos(stamp),
            );
        }

        if let Some(rgb) = f.rgb.take()
            && t.image.has_sinks()
        {
            match compressed(rgb) {
                Ok((format, data)) => t.image.log_with_time(
                    &fg::CompressedImage {
                        timestamp: timestamp(stamp),
                        frame_id: t.frame_id("camera_optical"),
                        data,
                        format: format.into(),
                    },
                    nanos(stamp),
                ),
                Err(e) => tracing::debug!(robot = %robot_id, "frame {} not shown: {e}", f.seq),
            }
        }
        if t.annotations.has_sinks() {
            t.annotations.log_with_time(&annotations(stamp, &seen), nanos(stamp));
        }
        if let Some(depth) = f.depth.take()
            && t.depth.has_sinks()
            && depth.data_mm.len() == depth.width as usize * depth.height as usize * 2
        {
            t.depth.log_with_time(
                &fg::RawImage {
                    timestamp: timestamp(stamp),
                    frame_id: t.frame_id("camera_optical"),
                    width: depth.width,
                    height: depth.height,
                    encoding: "16UC1".into(),
                    step: depth.width * 2,
                    data: depth.data_mm,
                },
                nanos(stamp),
            );
        }
        if t.no_go.has_sinks() {
            let mut data = Vec::with_capacity(seen.no_go.len() * 12);
            for p in &seen.no_go {
                for v in p {
                    data.extend_from_slice(&(*v as f32).to_le_bytes());
                }
            }
            let field = |name: &str, offset| fg::PackedElementField {
                name: name.into(),
                offset,
                r#type: fg::packed_element_field::NumericType::Float32 as i32,
            };
            t.no_go.log_with_time(
                &fg::PointCloud {
                    timestamp: timestamp(stamp),
                    frame_id: t.frame_id("base_link"),
                    pose: pose(0.0, 0.0, 0.0, yaw_quaternion(0.0)),
                    point_stride: 12,
                    fields: vec![field("x", 0), field("y", 4), field("z", 8)],
                    data: data.into(),
                },
                nanos(stamp),
            );
        }
        if t.scene.has_sinks() {
            t.scene.log_with_time(&scene(stamp, t, &robot.trail, &seen), nanos(stamp));
        }
        if t.status.has_sinks() {
            let status = status_json(stamp, mission.unwrap_or_default(), &seen, &command, &health);
            t.status.log_with_meta(status.to_string().as_bytes(), at());
        }

        if let Some(rec) = robot.recording.as_mut() {
            rec.frames += 1;
            if rec.frames.is_multiple_of(SIZE_CHECK_EVERY)
                && std::fs::metadata(&rec.current).is_ok_and(|m| m.len() >= max_bytes)
            {
                rotate(&ctx, &hub, &robot_id, rec, stamp);
            }
        }
    }
}

/// One message of `/<robot>/mission/status` (schema: `STATUS_SCHEMA`).
fn status_json(
    stamp: f64,
    mission: MissionView,
    seen: &Seen,
    command: &pb::VelocityCommand,
    health: &RobotHealth,
) -> serde_json::Value {
    let drive = seen.drive.as_ref();
    serde_json::json!({
        "mission_id": mission.mission_id,
        "state": if mission.mission_id.is_empty() { "idle".to_string() } else { mission.state },
        "step": mission.step.as_ref().map_or(-1, |s| s.0 as i64),
        "steps": mission.steps,
        "step_desc": mission.step.as_ref().map_or("", |s| s.1.as_str()),
        "drive_status": drive.map_or("".to_string(), |d| format!("{:?}", d.status).to_lowercase()),
        "distance_to_goal_m": drive.map_or(0.0, |d| d.distance_to_goal),
        "free_paths": drive.map_or(0, |d| d.free_paths),
        "boxes": seen.boxes.len(),
        "linear_mps": command.twist.map_or(0.0, |t| t.linear),
        "angular_radps": command.twist.map_or(0.0, |t| t.angular),
        "estop": health.estop,
        "platform_estop": health.platform_estop,
        // -1: the robot reports no charge (fleet.proto BatteryStatus).
        "battery_fraction": health.battery.as_ref().map_or(-1.0, |b| b.fraction),
        "battery_voltage": health.battery.as_ref().map_or(0.0, |b| b.voltage),
        "battery_low": health.battery.as_ref().is_some_and(|b| b.low),
        "stamp": stamp,
    })
}

/// Deletes the oldest `.mcap` files in `dir` (never one of `open`) until
/// the rest fit in `budget` bytes.
fn prune(dir: &Path, budget: u64, open: &[PathBuf]) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    let mut files: Vec<(std::time::SystemTime, u64, PathBuf)> = entries
        .filter_map(|e| e.ok())
        .filter(|e| e.path().extension().is_some_and(|x| x == "mcap"))
        .filter_map(|e| {
            let m = e.metadata().ok()?;
            Some((m.modified().ok()?, m.len(), e.path()))
        })
        .collect();
    let mut total: u64 = files.iter().map(|f| f.1).sum();
    files.sort();
    for (_, len, path) in files {
        if total <= budget {
            break;
        }
        if open.contains(&path) {
            continue;
        }
        match std::fs::remove_file(&path) {
            Ok(()) => {
                total -= len;
                tracing::info!("deleted the recording {} to keep recordings under the budget", path.display());
            }
            Err(e) => tracing::warn!("cannot delete the old recording {}: {e}", path.display()),
        }
    }
}

/// Opens one MCAP file for a robot's topics.
fn open_part(
    ctx: &Arc<Context>,
    robot_id: &str,
    path: &Path,
) -> Result<McapWriterHandle<BufWriter<std::fs::File>>, foxglove::FoxgloveError> {
    let prefix = format!("/{robot_id}/");
    ctx.mcap_writer().channel_filter_fn(move |c| c.topic().starts_with(&prefix)).create_new_buffered_file(path)
}

/// Continues a recording in its next file and tells the mission record.
fn rotate(ctx: &Arc<Context>, hub: &Hub, robot_id: &str, rec: &mut Recording, stamp: f64) {
    if let Some(handle) = rec.handle.take()
        && let Err(e) = handle.close()
    {
        tracing::error!(mission = %rec.mission_id, "cannot finish {}: {e}", rec.current.display());
    }
    rec.part += 1;
    let stem = rec.first.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let next = rec.first.with_file_name(format!("{stem}.part{}.mcap", rec.part));
    match open_part(ctx, robot_id, &next) {
        Ok(handle) => {
            rec.handle = Some(handle);
            rec.current = next.clone();
            let file = next.display().to_string();
            if let Err(e) = hub.record(&rec.mission_id, stamp, None, |m| m.recordings.push(file)) {
                tracing::warn!(mission = %rec.mission_id, "cannot note the recording's new file: {e}");
            }
        }
        Err(e) => {
            tracing::error!(mission = %rec.mission_id, "the recording stops: cannot open {}: {e}", next.display())
        }
    }
}

/// The camera image as the live view wants it: JPEG and PNG pass through,
/// raw RGB is encoded as JPEG.
fn compressed(rgb: pb::Image) -> Result<(&'static str, bytes::Bytes), String> {
    match pb::ImageEncoding::try_from(rgb.encoding) {
        Ok(pb::ImageEncoding::Jpeg) => Ok(("jpeg", rgb.data)),
        Ok(pb::ImageEncoding::Png) => Ok(("png", rgb.data)),
        Ok(pb::ImageEncoding::Rgb8) => {
            let out =
                vlnav_geometry::rgb::encode_jpeg(rgb.width, rgb.height, &rgb.data, 85).map_err(|e| e.to_string())?;
            Ok(("jpeg", out.into()))
        }
        _ => Err(format!("unknown image encoding {}", rgb.encoding)),
    }
}

/// Boxes with class and confidence; the target the executor tracks in green.
fn annotations(stamp: f64, seen: &Seen) -> fg::ImageAnnotations {
    let mut out = fg::ImageAnnotations::default();
    let mut draw = |d: &crate::executor::model::Detection, target: bool| {
        let (outline, thickness) =
            if target { (color(0.1, 0.9, 0.2, 1.0), 4.0) } else { (color(1.0, 0.6, 0.0, 1.0), 2.0) };
        let corners = [(d.x_min, d.y_min), (d.x_max, d.y_min), (d.x_max, d.y_max), (d.x_min, d.y_max)];
        out.points.push(fg::PointsAnnotation {
            timestamp: timestamp(stamp),
            r#type: fg::points_annotation::Type::LineLoop as i32,
            points: corners.iter().map(|&(x, y)| fg::Point2 { x: x as f64, y: y as f64 }).collect(),
            outline_color: outline,
            thickness,
            ..Default::default()
        });
        let label = if d.label.is_empty() {
            vlnav_proto::coco::name(d.class_id).unwrap_or("object").to_string()
        } else {
            d.label.clone()
        };
        out.texts.push(fg::TextAnnotation {
            timestamp: timestamp(stamp),
            position: Some(fg::Point2 { x: d.x_min as f64, y: (d.y_min as f64 - 4.0).max(12.0) }),
            text: format!("{}{label} {:.2}", if target { "TARGET " } else { "" }, d.score),
            font_size: 14.0,
            text_color: color(1.0, 1.0, 1.0, 1.0),
            background_color: outline,
            ..Default::default()
        });
    };
    let mut target_drawn = false;
    for d in &seen.boxes {
        let is_target = seen.target.as_ref() == Some(d);
        target_drawn |= is_target;
        draw(d, is_target);
    }
    if let Some(t) = &seen.target
        && !target_drawn
    {
        draw(t, true);
    }
    out
}

/// The 3-D scene: the trail since the last re-anchoring, the goal, the fused
/// target and the chosen primitive.
fn scene(stamp: f64, t: &Topics, trail: &[[f64; 2]], seen: &Seen) -> fg::SceneUpdate {
    let entity = |id: &str, frame: &str| fg::SceneEntity {
        timestamp: timestamp(stamp),
        frame_id: t.frame_id(frame),
        id: id.into(),
        ..Default::default()
    };
    let point = |x: f64, y: f64, z: f64| fg::Point3 { x, y, z };
    let line = |points: Vec<fg::Point3>, c: Option<fg::Color>, thickness: f64| fg::LinePrimitive {
        r#type: fg::line_primitive::Type::LineStrip as i32,
        pose: pose(0.0, 0.0, 0.0, yaw_quaternion(0.0)),
        thickness,
        scale_invariant: true,
        points,
        color: c,
        ..Default::default()
    };
    let mut entities = Vec::new();
    let mut deletions = Vec::new();
    let mut delete = |id: &str| {
        deletions.push(fg::SceneEntityDeletion {
            timestamp: timestamp(stamp),
            r#type: fg::scene_entity_deletion::Type::MatchingId as i32,
            id: id.into(),
        })
    };

    let mut trail_entity = entity("trail", "odom");
    trail_entity.lines.push(line(
        trail.iter().map(|p| point(p[0], p[1], 0.02)).collect(),
        color(0.2, 0.6, 1.0, 1.0),
        3.0,
    ));
    entities.push(trail_entity);

    match &seen.goal {
        Some(goal) => {
            let mut e = entity("goal", "odom");
            e.spheres.push(fg::SpherePrimitive {
                pose: pose(goal.pose.x, goal.pose.y, 0.1, yaw_quaternion(goal.pose.theta)),
                size: Some(fg::Vector3 { x: 0.2, y: 0.2, z: 0.2 }),
                color: color(1.0, 0.8, 0.0, 0.9),
            });
            e.arrows.push(fg::ArrowPrimitive {
                pose: pose(goal.pose.x, goal.pose.y, 0.1, yaw_quaternion(goal.pose.theta)),
                shaft_length: 0.4,
                shaft_diameter: 0.04,
                head_length: 0.12,
                head_diameter: 0.1,
                color: color(1.0, 0.8, 0.0, 0.9),
            });
            entities.push(e);
        }
        None => delete("goal"),
    }
    match seen.fused_target {
        Some([x, y, z]) => {
            let mut e = entity("target", "odom");
            e.cubes.push(fg::CubePrimitive {
                pose: pose(x, y, z, yaw_quaternion(0.0)),
                size: Some(fg::Vector3 { x: 0.3, y: 0.3, z: 0.3 }),
                color: color(0.1, 0.9, 0.2, 0.8),
            });
            entities.push(e);
        }
        None => delete("target"),
    }
    if seen.path.is_empty() {
        delete("primitive");
    } else {
        let mut e = entity("primitive", "base_link");
        e.lines.push(line(seen.path.iter().map(|p| point(p[0], p[1], 0.05)).collect(), color(1.0, 0.2, 0.8, 1.0), 4.0));
        entities.push(e);
    }
    fg::SceneUpdate { deletions, entities }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::executor::model::Detection;

    fn detection(x: f32, class_id: i32) -> Detection {
        Detection { x_min: x, y_min: 10.0, x_max: x + 20.0, y_max: 50.0, class_id, score: 0.8, label: String::new() }
    }

    #[test]
    fn the_target_is_highlighted_and_every_box_named() {
        let seen = Seen {
            boxes: vec![detection(0.0, 56), detection(100.0, 1)],
            target: Some(detection(100.0, 1)),
            ..Default::default()
        };
        let a = annotations(1.5, &seen);
        assert_eq!(a.points.len(), 2);
        assert_eq!(a.texts[0].text, "chair 0.80");
        assert_eq!(a.texts[1].text, "TARGET bicycle 0.80");
        assert!(a.points[1].thickness > a.points[0].thickness);
    }

    #[test]
    fn raw_rgb_is_compressed_and_bad_sizes_are_refused() {
        let rgb =
            pb::Image { width: 4, height: 2, encoding: pb::ImageEncoding::Rgb8 as i32, data: vec![128; 24].into() };
        let (format, data) = compressed(rgb).unwrap();
        assert_eq!(format, "jpeg");
        assert_eq!(&data[..2], &[0xFF, 0xD8]);
        let short =
            pb::Image { width: 4, height: 2, encoding: pb::ImageEncoding::Rgb8 as i32, data: vec![0; 5].into() };
        assert!(compressed(short).unwrap_err().contains("4×2×3 = 24"));
    }

    #[test]
    fn the_live_view_stays_on_loopback_unless_told_otherwise() {
        let mut o = ViewOptions::default();
        assert_eq!(o.live_addr().unwrap(), Some("127.0.0.1:8765".parse().unwrap()));
        o.live_view = "0.0.0.0:8765".into();
        assert!(o.live_addr().unwrap_err().to_string().contains("no credentials"));
        o.live_view_insecure = true;
        assert!(o.live_addr().unwrap().is_some());
        assert_eq!(ViewOptions::off().live_addr().unwrap(), None);
        o.live_view = "here".into();
        assert!(o.live_addr().unwrap_err().to_string().contains("not an address"));
    }

    /// A frame whose depth is noise: about 600 kB that no compressor shrinks.
    fn noisy_frame(seq: u64) -> pb::SensorFrame {
        let mut state = seq.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let data_mm = (0..640 * 480 * 2)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state as u8
            })
            .collect();
        pb::SensorFrame {
            frame: Some(pb::RgbdFrame {
                seq,
                stamp: seq as f64 * 0.1,
                depth: Some(pb::DepthImage { width: 640, height: 480, data_mm, encoding: 0, disparity_step: 0.0 }),
                ..Default::default()
            }),
            truth: None,
        }
    }

    /// Records `count` noisy frames of robot "r1" as mission "m-1", handed
    /// over as fast as `Viz::frame` returns, and waits until all is written.
    async fn record_noise(
        count: u64,
        lockstep: bool,
        record_max_mib: u64,
    ) -> (tempfile::TempDir, Arc<Hub>, Viz, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let hub = Hub::open(crate::store::Store::open(dir.path()).unwrap()).unwrap();
        hub.create(pb::Mission { mission_id: "m-1".into(), robot_id: "r1".into(), ..Default::default() }).unwrap();
        let opts = ViewOptions { live_view: "off".into(), record: true, record_max_mib, ..Default::default() };
        let viz = Viz::start(&opts, dir.path(), hub.clone()).unwrap();
        let first = viz.start_mission("r1", "m-1", pb::ActionPlan::default(), "go").unwrap();
        // Made before the hand-over, so that it is not slowed by making them.
        let frames: Vec<_> = (0..count).map(noisy_frame).collect();
        for frame in frames {
            let view = FrameView {
                robot_id: "r1".into(),
                frame,
                command: pb::VelocityCommand::default(),
                mission: None,
                seen: Seen::default(),
                health: RobotHealth::default(),
            };
            viz.frame(view, lockstep).await;
        }
        viz.end_mission("r1", "m-1");
        let v = viz.clone();
        tokio::task::spawn_blocking(move || v.flush()).await.unwrap();
        (dir, hub, viz, first)
    }

    /// A finished file's chunk count and its count of r1's raw frames.
    fn chunks_and_frames(file: &str) -> (u32, u64) {
        let bytes = std::fs::read(file).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().expect("a finished file has a summary");
        let stats = summary.stats.expect("statistics");
        let frames = summary
            .channels
            .iter()
            .filter(|(_, c)| c.topic == "/r1/sensor_frame")
            .map(|(id, _)| stats.channel_message_counts.get(id).copied().unwrap_or(0))
            .sum();
        (stats.chunk_count, frames)
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_long_recording_continues_in_new_files_that_the_mission_names() {
        // As a lockstep robot's: each frame waits for a place, none is dropped.
        let (_dir, hub, viz, first) = record_noise(2 * SIZE_CHECK_EVERY + 1, true, 1).await;
        let files = hub.get("m-1").unwrap().recordings;
        assert_eq!(files.len(), 3, "{files:?}");
        assert_eq!(files[0], first.display().to_string());
        assert!(files[1].ends_with("m-1.part2.mcap") && files[2].ends_with("m-1.part3.mcap"), "{files:?}");
        let mut frames = 0;
        for f in &files {
            let (chunks, n) = chunks_and_frames(f);
            assert!(chunks > 0, "{f} is chunked");
            frames += n;
        }
        assert_eq!(frames, 2 * SIZE_CHECK_EVERY + 1, "every frame is in one of the files");
        assert_eq!(viz.dropped_frames(), 0);
    }

    #[test]
    fn the_committed_layout_names_only_topics_and_frames_the_view_serves() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../deploy/foxglove/vlnav-layout.json");
        let layout: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let ctx = Context::new();
        let _topics = Topics::new(&ctx, "husky-1");
        let mut names = Vec::new();
        fn strings(v: &serde_json::Value, out: &mut Vec<String>) {
            match v {
                serde_json::Value::String(s) => out.push(s.clone()),
                serde_json::Value::Array(a) => a.iter().for_each(|v| strings(v, out)),
                serde_json::Value::Object(o) => o.iter().for_each(|(k, v)| {
                    out.push(k.clone());
                    strings(v, out)
                }),
                _ => {}
            }
        }
        strings(&layout, &mut names);
        let mut checked = 0;
        for name in names.iter().filter(|n| n.starts_with("/husky-1/")) {
            let topic = name.split('.').next().unwrap();
            assert!(
                ctx.get_channel_by_topic(topic).is_some(),
                "the layout names {topic}, which the view does not serve"
            );
            checked += 1;
        }
        assert!(checked >= 8, "the layout shows the robot's topics");
        for frame in names.iter().filter(|n| n.starts_with("husky-1/")) {
            assert!(["husky-1/odom", "husky-1/base_link"].contains(&frame.as_str()), "unknown frame {frame}");
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_real_time_robot_never_waits_its_frames_are_dropped_and_counted_instead() {
        let (_dir, hub, viz, _) = record_noise(200, false, 512).await;
        let dropped = viz.dropped_frames();
        assert!(dropped > 0, "200 frames of noise handed over at once outrun the writer");
        let (_, recorded) = chunks_and_frames(&hub.get("m-1").unwrap().recordings[0]);
        assert_eq!(recorded + dropped, 200, "every frame is either recorded or counted as dropped");
    }

    #[test]
    fn the_oldest_recordings_go_first_and_open_ones_stay() {
        let dir = tempfile::tempdir().unwrap();
        let names = ["a.mcap", "b.mcap", "c.mcap", "d.mcap"];
        for (i, name) in names.iter().enumerate() {
            let path = dir.path().join(name);
            std::fs::write(&path, vec![0u8; 1000]).unwrap();
            let t = std::time::SystemTime::UNIX_EPOCH + std::time::Duration::from_secs(1_000 + i as u64);
            std::fs::File::options().write(true).open(&path).unwrap().set_modified(t).unwrap();
        }
        std::fs::write(dir.path().join("notes.txt"), vec![0u8; 5000]).unwrap();
        // "a" is oldest but still being written.
        prune(dir.path(), 2000, &[dir.path().join("a.mcap")]);
        let left: Vec<bool> = names.iter().map(|n| dir.path().join(n).exists()).collect();
        assert_eq!(left, [true, false, false, true]);
        assert!(dir.path().join("notes.txt").exists(), "only recordings are deleted");
    }

    #[test]
    fn the_status_shows_the_robots_estop_and_battery() {
        let mission = MissionView { mission_id: "m-1".into(), state: "running".into(), ..Default::default() };
        let cmd = pb::VelocityCommand::default();
        let unknown = status_json(2.0, mission.clone(), &Seen::default(), &cmd, &RobotHealth::default());
        assert_eq!(unknown["battery_fraction"], -1.0, "{unknown}");
        assert_eq!(unknown["battery_low"], false);
        assert_eq!(unknown["estop"], false);
        let health = RobotHealth {
            estop: true,
            platform_estop: true,
            battery: Some(pb::BatteryStatus { stamp: 1.5, fraction: 0.15, voltage: 24.1, low: true }),
        };
        let low = status_json(2.0, mission, &Seen::default(), &cmd, &health);
        assert_eq!((low["battery_fraction"].as_f64(), low["battery_voltage"].as_f64()), (Some(0.15), Some(24.1)));
        assert_eq!((low["battery_low"].as_bool(), low["platform_estop"].as_bool()), (Some(true), Some(true)));
        assert_eq!(low["state"], "running");
        // Every field the message carries is in the schema Foxglove is given.
        let schema: serde_json::Value = serde_json::from_str(STATUS_SCHEMA).unwrap();
        for key in low.as_object().unwrap().keys() {
            assert!(schema["properties"].get(key).is_some(), "{key} is not in STATUS_SCHEMA");
        }
    }

    #[test]
    fn the_scene_forgets_a_goal_that_is_gone() {
        let ctx = Context::new();
        let topics = Topics::new(&ctx, "r1");
        let update = scene(2.0, &topics, &[[0.0, 0.0], [1.0, 0.0]], &Seen::default());
        assert_eq!(update.entities.len(), 1, "the trail only");
        assert_eq!(update.entities[0].frame_id, "r1/odom");
        let gone: Vec<_> = update.deletions.iter().map(|d| d.id.as_str()).collect();
        assert_eq!(gone, ["goal", "target", "primitive"]);
    }
}
