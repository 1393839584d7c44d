//! `vlnav bench fleet`: many simulated robots in real time on one gateway
//! (docs/architecture.md, "Fleet benchmark").
//!
//! Two processes, as in a deployment: this one runs the gateway and every
//! stage (the [`up`] stack, with TLS and tokens unless `--insecure`); a child
//! (`vlnav bench robots`, hidden) runs the robots — one edge agent and one
//! simulator per robot, each attached over its own gRPC connection with its
//! own certificate, stepping in real time at the frame rate. Each robot has a
//! dispatcher here, with its own operator token, that keeps a mission running
//! on it. The child measures every control cycle on the wall clock, frame
//! handed to the link → the command answering it (the agent's
//! [`LinkEvent`]s), so no clocks are compared across processes. CPU and
//! memory are read from `/proc` for each process.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt};
use tokio::sync::mpsc;
use vlnav_edge_agent::replay::Recorded;
use vlnav_edge_agent::{Codecs, EdgeOptions, Hooks, LinkEvent};
use vlnav_gateway::auth::{Role, TokenEntry, TokenFile};
use vlnav_proto::v1::{
    GetMissionRequest, ListRobotsRequest, MissionState, SubmitMissionRequest, WatchMissionRequest,
    fleet_service_client::FleetServiceClient, mission_service_client::MissionServiceClient,
    submit_mission_request::Instruction,
};
use vlnav_runtime::CancellationToken;
use vlnav_runtime::client::channel_with;
use vlnav_runtime::perception::PerceptionMode;
use vlnav_runtime::security::{ClientSecurity, DevPki, new_token, token_hash};

use crate::up::{StackSecurity, UpArgs, up};

/// What each robot is told, in turn: the paper's Case 2 (two searches, a
/// follow and a goal: every stage works), then a way back, then a short move.
pub const MISSIONS: [&str; 3] = [crate::CASE_2, "go back 3 m", "take a right turn and move 2 m ahead"];

/// The colour codec as reports name it: `raw`, or `jpeg` with its quality.
/// Megabits per second per robot of `bytes` sent by `robots` in `seconds`.
fn mbit_s_per_robot(bytes: u64, robots: usize, seconds: f64) -> f64 {
    if robots == 0 || seconds <= 0.0 { 0.0 } else { bytes as f64 * 8.0 / 1e6 / seconds / robots as f64 }
}

/// Robot ids of a benchmark run.
fn robot_id(i: usize) -> String {
    format!("bench-{i:03}")
}

#[derive(clap::Subcommand)]
pub enum BenchCmd {
    /// N simulated robots in real time on one gateway: control-cycle latency,
    /// frames dropped or late, CPU and memory (docs/architecture.md).
    Fleet(FleetArgs),
    /// Draws `vlnav bench fleet --json` lines (one file per series) as an SVG
    /// plot of cycle latency against the number of robots.
    Plot(PlotArgs),
    /// What JPEG colour on the robots' uplink (the edge agent's --colour-codec
    /// jpeg) costs NanoDet and the segmenter, and saves, per quality: recall
    /// and box IoU against known boxes and against the raw frames' detections,
    /// bytes, encode time, PSNR (docs/architecture.md, "Frames").
    Jpeg(vlnav_eval::jpeg_cost::JpegCostArgs),
    /// The robots' side of `bench fleet` (started by it).
    #[command(hide = true)]
    Robots(RobotsArgs),
}

#[derive(clap::Args, Clone, Debug)]
pub struct FleetArgs {
    /// Robots attached at once.
    #[arg(long, default_value_t = 10)]
    pub robots: usize,
    /// Run each count in turn (for example 1,10,50,100,200), one report each.
    #[arg(long, value_delimiter = ',')]
    pub sweep: Vec<usize>,
    /// Seconds measured, after every robot is attached and driving.
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// Seconds between the first missions and the measurement.
    #[arg(long, default_value_t = 5.0)]
    pub warmup: f64,
    /// One JSON object per run on stdout.
    #[arg(long)]
    pub json: bool,
    /// Perception of the stages: `oracle` (simulation backends, ground truth),
    /// `realistic` (the measured error model and the real segmenter).
    #[arg(long, value_enum, default_value_t = PerceptionMode::Oracle)]
    pub perception: PerceptionMode,
    /// Camera image size of every robot (the D455 streams 640×480).
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Camera frames per second of each robot.
    #[arg(long, default_value_t = 10.0)]
    pub frame_rate: f64,
    /// World of every robot (each robot has its own copy).
    #[arg(long, default_value = "demo")]
    pub scenario: String,
    #[command(flatten)]
    pub link: Codecs,
    /// While measuring, a client floods SubmitMission from 16 concurrent
    /// calls with its own token.
    #[arg(long)]
    pub flood: bool,
    /// Plaintext and no tokens (and so no per-caller submission limit).
    #[arg(long)]
    pub insecure: bool,
    /// Robots that send this mission recording's frames again (the gateway
    /// writes one per mission: `.vlnav/recordings/*.mcap`) instead of
    /// rendering a world: a robot then costs the machine next to nothing,
    /// so the run measures the stack. The frame size is the recording's
    /// (--width and --height are not used); its colour and depth are sent
    /// with --colour-codec and --depth-codec.
    #[arg(long)]
    pub replay: Option<PathBuf>,
    /// Frames of --replay held in memory and sent in turn (shared by every
    /// robot; 100 at 640×480 raw hold about 180 MB).
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..))]
    pub replay_frames: u64,
    /// When in each frame period the robots' cameras fire: `random`, each
    /// at its own phase (drawn from the robot's number), as the free-running
    /// cameras of separate robots do; `aligned`, all at the same moment, as
    /// robots started together do (the worst case).
    #[arg(long, value_enum, default_value_t = Phases::Random)]
    pub phases: Phases,
    /// Also trace every control cycle, with a trace receiver of this
    /// process writing to this directory, and report where the measured
    /// cycles' time goes along their critical path: the gateway's own work,
    /// each stage's (its server span) and each hop's (a call's client span
    /// less its server span: waiting for the connection, encoding, TLS and
    /// the network). Tracing costs CPU of its own, so a traced run's
    /// latency is not an untraced one's.
    #[arg(long)]
    pub traces: Option<PathBuf>,
}

/// When in each frame period the robots of a benchmark send their frames.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phases {
    Random,
    Aligned,
}

impl Phases {
    pub fn as_str(self) -> &'static str {
        match self {
            Phases::Random => "random",
            Phases::Aligned => "aligned",
        }
    }

    /// How long robot `i` waits before its first frame, as a share of the
    /// frame period: uniform in [0, 1) from `i` (SplitMix64), or 0.
    fn delay_share(self, i: usize) -> f64 {
        match self {
            Phases::Aligned => 0.0,
            Phases::Random => {
                let z = vlnav_runtime::perception::splitmix((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
                z as f64 / 2f64.powi(64)
            }
        }
    }
}

#[derive(clap::Args, Clone, Debug)]
pub struct RobotsArgs {
    #[arg(long)]
    pub gateway: String,
    /// The stack's credentials (the robots' certificates); absent: plaintext.
    #[arg(long)]
    pub security_dir: Option<PathBuf>,
    #[arg(long)]
    pub robots: usize,
    #[arg(long)]
    pub width: u32,
    #[arg(long)]
    pub height: u32,
    #[arg(long)]
    pub frame_rate: f64,
    #[arg(long)]
    pub scenario: String,
    #[command(flatten)]
    pub link: Codecs,
    #[arg(long)]
    pub replay: Option<PathBuf>,
    #[arg(long, default_value_t = 100)]
    pub replay_frames: u64,
    #[arg(long, value_enum, default_value_t = Phases::Aligned)]
    pub phases: Phases,
}

#[derive(clap::Args, Clone, Debug)]
pub struct PlotArgs {
    /// Files of `vlnav bench fleet --json` lines; each is one series.
    #[arg(required = true)]
    pub series: Vec<PathBuf>,
    #[arg(long)]
    pub out: PathBuf,
    /// Latency goal drawn as a line, milliseconds.
    #[arg(long, default_value_t = 50.0)]
    pub goal_ms: f64,
}

/// The robots' side of a run, as the child reports it.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct RobotsSummary {
    /// What the robots send: `rendered <scenario>` or `replayed <file>, <n> frames`.
    #[serde(default)]
    pub load: String,
    /// The robots' camera size.
    #[serde(default)]
    pub width: u32,
    #[serde(default)]
    pub height: u32,
    pub seconds: f64,
    pub frames_sent: u64,
    /// Bytes of the frames handed to the links (see [`LinkEvent::Frame`]).
    #[serde(default)]
    pub frame_bytes: u64,
    /// Of those, the colour and depth data.
    #[serde(default)]
    pub image_bytes: u64,
    pub dropped_at_edge: u64,
    pub unanswered: u64,
    pub cycles: u64,
    pub idle_cycles: u64,
    pub late: u64,
    pub cycle_p50_ms: f64,
    pub cycle_p99_ms: f64,
    pub cycle_max_ms: f64,
    pub worst_robot_p99_ms: f64,
    pub cpu_percent: f64,
    pub rss_mib: f64,
}

/// Submissions of the flooding client while measuring.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct FloodReport {
    pub requests: u64,
    pub resource_exhausted: u64,
    pub unavailable: u64,
    pub admitted: u64,
    pub other: u64,
    /// Slowest answer to a flooding call, milliseconds.
    pub slowest_answer_ms: f64,
}

/// One run of `vlnav bench fleet`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct FleetReport {
    pub robots: usize,
    pub seconds: f64,
    pub perception: String,
    pub width: u32,
    pub height: u32,
    pub frame_rate: f64,
    /// What the robots send: `rendered <scenario>` (each robot renders its
    /// world) or `replayed <file>, <n> frames` (`--replay`).
    #[serde(default)]
    pub load: String,
    /// `random` or `aligned` (`--phases`); empty in reports from before
    /// the option, whose robots were aligned.
    #[serde(default)]
    pub phases: String,
    #[serde(default)]
    pub depth_codec: String,
    /// `raw`, or `jpeg q<quality>`.
    #[serde(default)]
    pub colour_codec: String,
    /// The uplink of each robot, megabits per second: bytes of the frames
    /// it sent (each frame's message as encoded, labels included) over the
    /// seconds measured.
    #[serde(default)]
    pub uplink_mbit_s_per_robot: f64,
    /// Of that, the colour and depth data: the uplink of a real robot,
    /// which sends no label image.
    #[serde(default)]
    pub image_mbit_s_per_robot: f64,
    /// Frames each robot actually sent per second (below `frame_rate` when
    /// the robots' own simulation cannot keep up).
    pub achieved_frame_rate: f64,
    pub frames_sent: u64,
    /// Frames answered while a mission drove the robot: the control cycles measured.
    pub cycles: u64,
    pub idle_cycles: u64,
    pub cycle_p50_ms: f64,
    pub cycle_p99_ms: f64,
    pub cycle_max_ms: f64,
    pub worst_robot_p99_ms: f64,
    /// Answered after more than one frame period.
    pub late_frames: u64,
    /// Never answered: dropped at the robot (link queue full) or passed over
    /// by the gateway for a newer frame.
    pub dropped_frames: u64,
    pub dropped_at_edge: u64,
    pub skipped_by_gateway: u64,
    pub missions_started: u64,
    pub missions_succeeded: u64,
    pub missions_failed: u64,
    pub submissions_refused: u64,
    /// Gateway and every stage (one process).
    pub stack_cpu_percent: f64,
    pub stack_rss_mib: f64,
    /// The stack's CPU time per frame that reached the gateway (sent and not
    /// dropped at the robot), milliseconds: the gateway and every stage.
    #[serde(default)]
    pub stack_cpu_ms_per_frame: f64,
    /// Robots at `frame_rate` that this machine's cores could serve if the
    /// stack did nothing but this work: cores ÷ (CPU per frame × frame rate).
    #[serde(default)]
    pub compute_bound_robots: f64,
    /// The stack's busiest threads by name, CPU percent (100 = one core): a
    /// stage whose actor thread nears 100 % is the bottleneck.
    #[serde(default)]
    pub stack_threads: Vec<(String, f64)>,
    /// The simulated robots (the other process).
    pub robots_cpu_percent: f64,
    pub robots_rss_mib: f64,
    pub flood: Option<FloodReport>,
    /// Why the run could not be measured (a sweep goes on to the next count).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// With `--traces`: the control cycles of the measured interval found
    /// in the traces.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub traced_cycles: usize,
    /// With `--traces`: where those cycles' time goes, the largest share
    /// first (`tools/traces/src/profile.rs`, critical path).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub critical_path: Vec<PathPart>,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// One span name's time on the control cycles' critical path.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PathPart {
    /// The span: `control-cycle` (the gateway's own work), a stage's server
    /// span (`detect`, …), a call's client span (`call Detect`, …: the hop).
    pub name: String,
    /// `internal`, `server` or `client`.
    pub kind: String,
    /// Mean per cycle (over all cycles), ms.
    pub mean_ms: f64,
    /// p95 over the cycles it is on the path in, ms.
    pub p95_ms: f64,
    /// Share of all cycle time.
    pub share: f64,
}

/// The control cycles that started and ended within `[from_ns, to_ns]`
/// (Unix time) in the span files of `dir`: how many, and their critical
/// path's parts.
fn traced_path(dir: &Path, from_ns: u64, to_ns: u64) -> anyhow::Result<(usize, Vec<PathPart>)> {
    let store = vlnav_traces::SpanStore::open(dir)?;
    let mut spans = Vec::new();
    for id in store.trace_ids()? {
        spans.extend(store.spans_of_trace(&id)?);
    }
    let within = |s: &vlnav_traces::Span| s.start_ns >= from_ns && s.end_ns <= to_ns;
    let Some(cl) = vlnav_traces::control_loop_of(&spans, vlnav_traces::CONTROL_CYCLE, within) else {
        return Ok((0, Vec::new()));
    };
    let parts = cl
        .shares
        .iter()
        .map(|p| PathPart {
            name: p.stage.name.clone(),
            kind: p.stage.kind.as_str().to_string(),
            mean_ms: p.mean_ms,
            p95_ms: p.p95_ms,
            share: p.share,
        })
        .collect();
    Ok((cl.cycles, parts))
}

fn unix_ns() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

impl std::fmt::Display for FleetReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(e) = &self.error {
            return write!(f, "{} robots, {}x{}: not measured: {e}", self.robots, self.width, self.height);
        }
        writeln!(
            f,
            "{} robots ({}{}), {}x{} at {} fps ({:.1} achieved), {} colour, {} depth, {} perception, {:.0} s measured{}",
            self.robots,
            if self.load.is_empty() { "rendered" } else { &self.load },
            if self.phases.is_empty() { String::new() } else { format!(", {} phases", self.phases) },
            self.width,
            self.height,
            self.frame_rate,
            self.achieved_frame_rate,
            self.colour_codec,
            self.depth_codec,
            self.perception,
            self.seconds,
            if self.flood.is_some() { ", while a client floods SubmitMission" } else { "" }
        )?;
        writeln!(
            f,
            "  control cycle (frame in → command out): p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms; worst robot's p99 {:.1} ms",
            self.cycle_p50_ms, self.cycle_p99_ms, self.cycle_max_ms, self.worst_robot_p99_ms
        )?;
        writeln!(
            f,
            "  uplink per robot: {:.1} Mbit/s of frames, {:.1} Mbit/s of it colour and depth (the rest: the simulator's labels)",
            self.uplink_mbit_s_per_robot, self.image_mbit_s_per_robot
        )?;
        writeln!(
            f,
            "  frames: {} sent, {} mission cycles, {} idle; {} late (> one frame period), {} dropped ({} at the robot, {} passed over for a newer one)",
            self.frames_sent,
            self.cycles,
            self.idle_cycles,
            self.late_frames,
            self.dropped_frames,
            self.dropped_at_edge,
            self.skipped_by_gateway
        )?;
        writeln!(
            f,
            "  missions: {} started, {} succeeded, {} failed; {} submissions refused",
            self.missions_started, self.missions_succeeded, self.missions_failed, self.submissions_refused
        )?;
        write!(
            f,
            "  CPU: stack {:.0} %, robots {:.0} % (100 % = one core); memory: stack {:.0} MiB, robots {:.0} MiB",
            self.stack_cpu_percent, self.robots_cpu_percent, self.stack_rss_mib, self.robots_rss_mib
        )?;
        if self.stack_cpu_ms_per_frame > 0.0 {
            write!(
                f,
                "\n  stack CPU per frame {:.1} ms: this machine's cores could serve {:.1} robots at {} fps (the compute bound)",
                self.stack_cpu_ms_per_frame, self.compute_bound_robots, self.frame_rate
            )?;
        }
        if !self.stack_threads.is_empty() {
            let threads: Vec<String> = self.stack_threads.iter().map(|(n, p)| format!("{n} {p:.0} %")).collect();
            write!(f, "\n  busiest stack threads: {}", threads.join(", "))?;
        }
        if !self.critical_path.is_empty() {
            let parts: Vec<String> = self
                .critical_path
                .iter()
                .map(|p| {
                    let own = if p.name == vlnav_traces::CONTROL_CYCLE { " (gateway's own)" } else { "" };
                    format!("{}{own} [{}] {:.2} ms ({:.0} %)", p.name, p.kind, p.mean_ms, 100.0 * p.share)
                })
                .collect();
            write!(
                f,
                "\n  where a traced cycle's time goes ({} cycles, mean per cycle on the critical path): {}",
                self.traced_cycles,
                parts.join(", ")
            )?;
        }
        if let Some(fl) = &self.flood {
            write!(
                f,
                "\n  flood: {} calls, {} RESOURCE_EXHAUSTED, {} UNAVAILABLE, {} admitted, {} other; slowest answer {:.1} ms",
                fl.requests, fl.resource_exhausted, fl.unavailable, fl.admitted, fl.other, fl.slowest_answer_ms
            )?;
        }
        Ok(())
    }
}

/// CPU seconds (user + system, every thread) and resident memory of a process.
fn proc_usage(pid: u32) -> anyhow::Result<(f64, f64)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).context("reading /proc (Linux only)")?;
    // Fields after the command name, which is in parentheses and may hold spaces.
    let rest = stat.rsplit_once(')').map(|(_, r)| r).unwrap_or("");
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of stat(5): 12 and 13 after the name and state.
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // USER_HZ is 100 on every Linux architecture vlnav runs on.
    let cpu = (ticks(11) + ticks(12)) / 100.0;
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let rss_kib = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or(0.0);
    Ok((cpu, rss_kib / 1024.0))
}

/// CPU seconds of every thread of a process, by thread id, with its name.
fn thread_usage(pid: u32) -> std::collections::HashMap<u32, (String, f64)> {
    let mut out = std::collections::HashMap::new();
    let Ok(dir) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return out };
    for entry in dir.flatten() {
        let Some(tid) = entry.file_name().to_str().and_then(|t| t.parse::<u32>().ok()) else { continue };
        let Ok(stat) = std::fs::read_to_string(entry.path().join("stat")) else { continue };
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else { continue };
        let name = stat[open + 1..close].to_string();
        let fields: Vec<&str> = stat[close + 1..].split_whitespace().collect();
        let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
        out.insert(tid, (name, (ticks(11) + ticks(12)) / 100.0));
    }
    out
}

/// The busiest kinds of thread between two [`thread_usage`] readings: CPU
/// percent (100 = one core) summed by thread name, busiest first.
fn busiest(
    before: &std::collections::HashMap<u32, (String, f64)>,
    after: &std::collections::HashMap<u32, (String, f64)>,
    seconds: f64,
    top: usize,
) -> Vec<(String, f64)> {
    let mut by_name: std::collections::BTreeMap<String, f64> = Default::default();
    for (tid, (name, cpu)) in after {
        let base = before.get(tid).map_or(0.0, |(_, c)| *c);
        *by_name.entry(name.clone()).or_default() += (cpu - base).max(0.0) / seconds.max(1e-9) * 100.0;
    }
    let mut v: Vec<(String, f64)> = by_name.into_iter().filter(|(_, p)| *p >= 0.5).collect();
    v.sort_by(|a, b| b.1.total_cmp(&a.1));
    v.truncate(top);
    v
}

/// The `q` quantile (0–1) of sorted values; 0 when empty.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let i = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    sorted[i]
}

/// Cycle bookkeeping of one robot, fed by its agent's link events.
#[derive(Debug, Default)]
struct CycleStats {
    /// Frames handed to the link and not yet answered, oldest first, and
    /// whether each was sent while measuring (only those are counted).
    pending: VecDeque<(f64, Instant, bool)>,
    sent: u64,
    /// Bytes of the frames queued while measuring, and of their images.
    bytes: u64,
    image_bytes: u64,
    dropped_at_edge: u64,
    unanswered: u64,
    idle: u64,
    late: u64,
    cycles_ms: Vec<f64>,
}

impl CycleStats {
    /// Records `event`; counts only while `measuring`.
    fn on(&mut self, event: LinkEvent, measuring: bool, period: f64) {
        match event {
            LinkEvent::Frame { stamp, queued, at, bytes, image_bytes } => {
                if measuring {
                    self.sent += 1;
                    self.dropped_at_edge += u64::from(!queued);
                    if queued {
                        self.bytes += bytes as u64;
                        self.image_bytes += image_bytes as u64;
                    }
                }
                if queued {
                    self.pending.push_back((stamp, at, measuring));
                }
            }
            LinkEvent::Command { stamp, idle, at } => {
                // Older frames still waiting were passed over: the gateway answers the newest.
                while let Some(&(s, _, counted)) = self.pending.front() {
                    if s >= stamp - 1e-9 {
                        break;
                    }
                    self.pending.pop_front();
                    self.unanswered += u64::from(counted && measuring);
                }
                let Some(&(s, sent, counted)) = self.pending.front() else { return };
                if (s - stamp).abs() > 1e-9 {
                    return;
                }
                self.pending.pop_front();
                if !(counted && measuring) {
                    return;
                }
                let ms = at.saturating_duration_since(sent).as_secs_f64() * 1e3;
                if ms > period * 1e3 {
                    self.late += 1;
                }
                if idle {
                    self.idle += 1;
                } else {
                    self.cycles_ms.push(ms);
                }
            }
        }
    }
}

/// `vlnav bench robots`: runs the robots until told `stop` on stdin, then
/// prints one [`RobotsSummary`] line. Measures between `start` and `stop`.
pub async fn robots(args: &RobotsArgs) -> anyhow::Result<()> {
    let pki = match &args.security_dir {
        Some(dir) => Some(DevPki::ensure(dir, &[])?),
        None => None,
    };
    let codecs = args.link;
    let (recorded, load) = match &args.replay {
        Some(file) => {
            let frames = crate::replay::read_frames(file, args.replay_frames.try_into().unwrap_or(usize::MAX))?;
            let recorded = Recorded::new(frames, codecs).with_context(|| format!("replaying {}", file.display()))?;
            let name = file.file_name().map_or_else(|| file.display().to_string(), |n| n.to_string_lossy().into());
            let load = format!("replayed {name}, {} frames", recorded.len());
            (Some(recorded), load)
        }
        None => (None, format!("rendered {}", args.scenario)),
    };
    let (width, height) = match &recorded {
        Some(r) => (r.camera().width, r.camera().height),
        None => (args.width, args.height),
    };
    let measuring = Arc::new(AtomicBool::new(false));
    let shutdown = CancellationToken::new();
    let period = 1.0 / args.frame_rate;
    let mut stats = Vec::new();
    for i in 0..args.robots {
        let id = robot_id(i);
        let mut opts = EdgeOptions {
            gateway: args.gateway.clone(),
            robot_id: id.clone(),
            scenario: args.scenario.clone(),
            seed: i as u64,
            lockstep: false,
            frame_rate: args.frame_rate,
            width: Some(args.width),
            height: Some(args.height),
            ..EdgeOptions::default()
        }
        .with_codecs(codecs);
        if let Some(pki) = &pki {
            opts.tls = pki.client_args(Some((pki.robot_cert(&id), pki.robot_key(&id))));
        }
        let (tx, mut rx) = mpsc::unbounded_channel();
        let hooks = Hooks { timing: Some(tx), ..Hooks::default() };
        let token = shutdown.clone();
        let recorded = recorded.clone();
        let delay = Duration::from_secs_f64(period * args.phases.delay_share(i));
        tokio::spawn(async move {
            tokio::time::sleep(delay).await;
            let run = match recorded {
                Some(r) => vlnav_edge_agent::replay::run_replay(&opts, r, token, hooks).await,
                None => vlnav_edge_agent::run_with(opts, token, hooks).await,
            };
            if let Err(e) = run {
                eprintln!("robot {id}: {e:#}");
            }
        });
        let s = Arc::new(Mutex::new(CycleStats::default()));
        stats.push(s.clone());
        let m = measuring.clone();
        tokio::spawn(async move {
            while let Some(e) = rx.recv().await {
                let on = m.load(Ordering::Relaxed);
                s.lock().unwrap_or_else(|p| p.into_inner()).on(e, on, period);
            }
        });
    }
    let pid = std::process::id();
    let mut lines = tokio::io::BufReader::new(tokio::io::stdin()).lines();
    let mut started = None;
    while let Some(line) = lines.next_line().await? {
        match line.trim() {
            "start" => {
                started = Some((Instant::now(), proc_usage(pid)?.0));
                measuring.store(true, Ordering::Relaxed);
            }
            "stop" => break,
            _ => {}
        }
    }
    measuring.store(false, Ordering::Relaxed);
    let (cpu1, rss) = proc_usage(pid)?;
    shutdown.cancel();
    let (t0, cpu0) = started.unwrap_or((Instant::now(), cpu1));
    let seconds = t0.elapsed().as_secs_f64();
    let mut summary = RobotsSummary { load, width, height, seconds, rss_mib: rss, ..Default::default() };
    summary.cpu_percent = if seconds > 0.0 { (cpu1 - cpu0) / seconds * 100.0 } else { 0.0 };
    let mut all = Vec::new();
    for s in &stats {
        let mut s = s.lock().unwrap_or_else(|p| p.into_inner());
        summary.frames_sent += s.sent;
        summary.frame_bytes += s.bytes;
        summary.image_bytes += s.image_bytes;
        summary.dropped_at_edge += s.dropped_at_edge;
        summary.unanswered += s.unanswered;
        summary.idle_cycles += s.idle;
        summary.late += s.late;
        s.cycles_ms.sort_by(f64::total_cmp);
        summary.worst_robot_p99_ms = summary.worst_robot_p99_ms.max(quantile(&s.cycles_ms, 0.99));
        all.extend_from_slice(&s.cycles_ms);
    }
    all.sort_by(f64::total_cmp);
    summary.cycles = all.len() as u64;
    summary.cycle_p50_ms = quantile(&all, 0.5);
    summary.cycle_p99_ms = quantile(&all, 0.99);
    summary.cycle_max_ms = all.last().copied().unwrap_or(0.0);
    println!("{}", serde_json::to_string(&summary)?);
    Ok(())
}

#[derive(Default)]
struct MissionCounts {
    started: AtomicU64,
    succeeded: AtomicU64,
    failed: AtomicU64,
    refused: AtomicU64,
}

/// Keeps a mission running on `robot`: submit, watch it to its end, next.
async fn dispatch(
    gateway: String,
    security: ClientSecurity,
    robot: String,
    first: usize,
    counts: Arc<MissionCounts>,
    stop: CancellationToken,
) -> anyhow::Result<()> {
    let mut client = MissionServiceClient::new(channel_with(&gateway, &security)?);
    let mut i = first;
    while !stop.is_cancelled() {
        let text = MISSIONS[i % MISSIONS.len()];
        i += 1;
        let request = SubmitMissionRequest {
            robot_id: robot.clone(),
            instruction: Some(Instruction::Text(text.into())),
            dry_run: false,
        };
        let submitted = tokio::select! {
            _ = stop.cancelled() => return Ok(()),
            r = client.submit_mission(request) => r,
        };
        let id = match submitted {
            Ok(r) => r.into_inner().mission_id,
            Err(status) => {
                counts.refused.fetch_add(1, Ordering::Relaxed);
                tracing::debug!(robot, "submission refused: {}", status.message());
                tokio::select! {
                    _ = stop.cancelled() => return Ok(()),
                    _ = tokio::time::sleep(Duration::from_secs(1)) => continue,
                }
            }
        };
        counts.started.fetch_add(1, Ordering::Relaxed);
        let follow = async {
            let mut events = client.watch_mission(WatchMissionRequest { mission_id: id.clone() }).await?.into_inner();
            while events.message().await?.is_some() {}
            anyhow::Ok(client.get_mission(GetMissionRequest { mission_id: id.clone() }).await?.into_inner())
        };
        let mission = tokio::select! {
            _ = stop.cancelled() => return Ok(()),
            m = follow => m,
        };
        match mission {
            Ok(m) if m.state == MissionState::Succeeded as i32 => counts.succeeded.fetch_add(1, Ordering::Relaxed),
            _ => counts.failed.fetch_add(1, Ordering::Relaxed),
        };
    }
    Ok(())
}

/// Floods SubmitMission from 16 concurrent loops until `stop`.
async fn flood(gateway: String, security: ClientSecurity, robot: String, stop: CancellationToken) -> FloodReport {
    let report = Arc::new(Mutex::new(FloodReport::default()));
    let mut tasks = Vec::new();
    for _ in 0..16 {
        let (gateway, security, robot, stop, report) =
            (gateway.clone(), security.clone(), robot.clone(), stop.clone(), report.clone());
        tasks.push(tokio::spawn(async move {
            let Ok(channel) = channel_with(&gateway, &security) else { return };
            let mut client = MissionServiceClient::new(channel);
            while !stop.is_cancelled() {
                let t = Instant::now();
                let r = client
                    .submit_mission(SubmitMissionRequest {
                        robot_id: robot.clone(),
                        instruction: Some(Instruction::Text("move 1 m ahead".into())),
                        dry_run: true,
                    })
                    .await;
                let ms = t.elapsed().as_secs_f64() * 1e3;
                let mut rep = report.lock().unwrap_or_else(|p| p.into_inner());
                rep.requests += 1;
                rep.slowest_answer_ms = rep.slowest_answer_ms.max(ms);
                match r {
                    Ok(_) => rep.admitted += 1,
                    Err(s) if s.code() == tonic::Code::ResourceExhausted => rep.resource_exhausted += 1,
                    Err(s) if s.code() == tonic::Code::Unavailable => rep.unavailable += 1,
                    Err(_) => rep.other += 1,
                }
            }
        }));
    }
    for t in tasks {
        let _ = t.await;
    }
    report.lock().unwrap_or_else(|p| p.into_inner()).clone()
}

/// Adds one operator token per robot (each robot's dispatcher is its own
/// caller, as separate users would be) and one for the flooding client.
fn issue_tokens(sec: &StackSecurity, robots: &[String]) -> anyhow::Result<(Vec<String>, String)> {
    let path = &sec.tokens_file;
    let mut file = TokenFile::parse(&std::fs::read_to_string(path)?, path)?;
    let mut entry = |name: String, robots: Option<Vec<String>>| {
        let token = new_token();
        file.tokens.push(TokenEntry {
            name,
            role: Role::Operator,
            sha256: token_hash(&token),
            robots,
            expires_unix: None,
        });
        token
    };
    let tokens = robots.iter().map(|r| entry(format!("dispatcher-{r}"), Some(vec![r.clone()]))).collect();
    let flood = entry("flooding-client".into(), None);
    std::fs::write(path, file.to_toml())?;
    Ok((tokens, flood))
}

/// One run of `vlnav bench fleet` with `n` robots.
pub async fn fleet_run(args: &FleetArgs, n: usize) -> anyhow::Result<FleetReport> {
    anyhow::ensure!(n >= 1, "--robots must be at least 1");
    anyhow::ensure!(
        args.seconds > 0.0 && args.seconds.is_finite() && args.warmup >= 0.0,
        "--seconds must be positive and --warmup not negative"
    );
    anyhow::ensure!(!(args.flood && args.insecure), "--flood needs tokens (the limit is per caller): drop --insecure");
    let data = tempfile::tempdir()?;
    let ids: Vec<String> = (0..n).map(robot_id).collect();
    let security_dir = data.path().join("security");
    let (tokens, flood_token) = if args.insecure {
        (Vec::new(), String::new())
    } else {
        let refs: Vec<&str> = ids.iter().map(String::as_str).collect();
        let sec = StackSecurity::ensure(&security_dir, &refs)?;
        issue_tokens(&sec, &ids)?
    };
    let up_args = UpArgs {
        no_robot: true,
        ephemeral_ports: true,
        data_dir: data.path().to_path_buf(),
        insecure: args.insecure,
        perception: args.perception,
        // As deployed: 60 a minute per caller (each dispatcher is one caller).
        submit_per_minute: if args.insecure { 0 } else { 60 },
        ..UpArgs::default()
    };
    let stack = up(&up_args).await?;
    let uri = stack.gateway_uri();
    let caller = |token: &str| -> anyhow::Result<ClientSecurity> {
        match &stack.security {
            Some(s) => Ok(ClientSecurity::new(s.pki.client_args(None).load()?, Some(token.to_string()))),
            None => Ok(ClientSecurity::none()),
        }
    };

    let mut child = tokio::process::Command::new(std::env::current_exe()?);
    child
        .args(["bench", "robots", "--gateway", &uri, "--robots", &n.to_string()])
        .args(["--width", &args.width.to_string(), "--height", &args.height.to_string()])
        .args(["--frame-rate", &args.frame_rate.to_string(), "--scenario", &args.scenario])
        .args(args.link.to_flags())
        .args(["--replay-frames", &args.replay_frames.to_string()])
        .args(["--phases", args.phases.as_str()])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .kill_on_drop(true);
    if !args.insecure {
        child.arg("--security-dir").arg(&security_dir);
    }
    if let Some(file) = &args.replay {
        child.arg("--replay").arg(file);
    }
    let mut child = child.spawn().context("starting the robots' process")?;
    let mut to_child = child.stdin.take().context("no stdin to the robots' process")?;
    let from_child = child.stdout.take().context("no stdout from the robots' process")?;

    // The measured interval in Unix time (for --traces).
    let mut window = (0_u64, 0_u64);
    let result = async {
        // Every robot attached and sending.
        let mut fleet = FleetServiceClient::new(channel_with(&uri, &stack.operator()?)?);
        let deadline = Instant::now() + Duration::from_secs_f64(30.0 + n as f64 * 0.5);
        loop {
            let robots = fleet.list_robots(ListRobotsRequest {}).await?.into_inner().robots;
            let ready = robots.iter().filter(|r| r.connected && r.frames_received > 0).count();
            if ready >= n {
                break;
            }
            anyhow::ensure!(Instant::now() < deadline, "only {ready} of {n} robots attached in time");
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        let stop = CancellationToken::new();
        let counts = Arc::new(MissionCounts::default());
        for (i, id) in ids.iter().enumerate() {
            let security = caller(tokens.get(i).map(String::as_str).unwrap_or(""))?;
            let (uri, id, counts, stop) = (uri.clone(), id.clone(), counts.clone(), stop.clone());
            tokio::spawn(async move {
                if let Err(e) = dispatch(uri, security, id.clone(), i, counts, stop).await {
                    tracing::warn!(robot = %id, "dispatcher stopped: {e:#}");
                }
            });
        }
        tokio::time::sleep(Duration::from_secs_f64(args.warmup)).await;

        let skipped = |robots: &[vlnav_proto::v1::RobotInfo]| robots.iter().map(|r| r.frames_skipped).sum::<u64>();
        let skipped0 = skipped(&fleet.list_robots(ListRobotsRequest {}).await?.into_inner().robots);
        let started0 = counts.started.load(Ordering::Relaxed);
        let refused0 = counts.refused.load(Ordering::Relaxed);
        let (succeeded0, failed0) = (counts.succeeded.load(Ordering::Relaxed), counts.failed.load(Ordering::Relaxed));
        let me = std::process::id();
        let (cpu0, _) = proc_usage(me)?;
        let threads0 = thread_usage(me);
        let t0 = Instant::now();
        window.0 = unix_ns();
        to_child.write_all(b"start\n").await?;
        let flooding = if args.flood {
            let stop = stop.child_token();
            let task = tokio::spawn(flood(uri.clone(), caller(&flood_token)?, ids[0].clone(), stop.clone()));
            Some((stop, task))
        } else {
            None
        };
        tokio::time::sleep(Duration::from_secs_f64(args.seconds)).await;
        to_child.write_all(b"stop\n").await?;
        window.1 = unix_ns();
        let seconds = t0.elapsed().as_secs_f64();
        let (cpu1, rss) = proc_usage(me)?;
        let stack_threads = busiest(&threads0, &thread_usage(me), seconds, 6);
        let skipped1 = skipped(&fleet.list_robots(ListRobotsRequest {}).await?.into_inner().robots);
        let flood = match flooding {
            Some((stop, task)) => {
                stop.cancel();
                Some(task.await?)
            }
            None => None,
        };
        let mut line = String::new();
        tokio::io::BufReader::new(from_child).read_line(&mut line).await?;
        let robots: RobotsSummary = serde_json::from_str(line.trim())
            .with_context(|| format!("the robots' process reported {line:?} (its errors are above)"))?;
        stop.cancel();
        let started = counts.started.load(Ordering::Relaxed) - started0;
        // Frames that reached the gateway: sent, and not dropped at the robot.
        let cpu_ms = cpu_ms_per_frame(cpu1 - cpu0, robots.frames_sent - robots.dropped_at_edge);
        measured(
            &robots,
            started,
            &format!("{n} robots at {}x{} and {} fps", robots.width, robots.height, args.frame_rate),
        )?;
        Ok(FleetReport {
            robots: n,
            seconds,
            perception: args.perception.as_str().into(),
            width: robots.width,
            height: robots.height,
            frame_rate: args.frame_rate,
            load: robots.load.clone(),
            phases: args.phases.as_str().into(),
            depth_codec: args.link.depth_name(),
            colour_codec: args.link.colour_name(),
            uplink_mbit_s_per_robot: mbit_s_per_robot(robots.frame_bytes, n, robots.seconds),
            image_mbit_s_per_robot: mbit_s_per_robot(robots.image_bytes, n, robots.seconds),
            achieved_frame_rate: robots.frames_sent as f64 / (n as f64 * robots.seconds.max(1e-9)),
            frames_sent: robots.frames_sent,
            cycles: robots.cycles,
            idle_cycles: robots.idle_cycles,
            cycle_p50_ms: robots.cycle_p50_ms,
            cycle_p99_ms: robots.cycle_p99_ms,
            cycle_max_ms: robots.cycle_max_ms,
            worst_robot_p99_ms: robots.worst_robot_p99_ms,
            late_frames: robots.late,
            dropped_frames: robots.dropped_at_edge + robots.unanswered,
            dropped_at_edge: robots.dropped_at_edge,
            skipped_by_gateway: skipped1.saturating_sub(skipped0),
            missions_started: counts.started.load(Ordering::Relaxed) - started0,
            missions_succeeded: counts.succeeded.load(Ordering::Relaxed) - succeeded0,
            missions_failed: counts.failed.load(Ordering::Relaxed) - failed0,
            submissions_refused: counts.refused.load(Ordering::Relaxed) - refused0,
            stack_cpu_percent: (cpu1 - cpu0) / seconds * 100.0,
            stack_cpu_ms_per_frame: cpu_ms,
            compute_bound_robots: compute_bound(cpu_ms, args.frame_rate, cores()),
            stack_rss_mib: rss,
            stack_threads,
            robots_cpu_percent: robots.cpu_percent,
            robots_rss_mib: robots.rss_mib,
            flood,
            error: None,
            traced_cycles: 0,
            critical_path: Vec::new(),
        })
    }
    .await;
    drop(to_child);
    let _ = tokio::time::timeout(Duration::from_secs(10), child.wait()).await;
    let _ = child.kill().await;
    stack.shutdown().await?;
    let mut report = result?;
    if let Some(dir) = &args.traces {
        // Spans leave in batches every 200 ms (crates/runtime/src/telemetry.rs).
        tokio::time::sleep(Duration::from_secs(2)).await;
        (report.traced_cycles, report.critical_path) = traced_path(dir, window.0, window.1)?;
        anyhow::ensure!(
            report.traced_cycles > 0,
            "--traces: no control cycle of the measured interval reached {}",
            dir.display()
        );
    }
    Ok(report)
}

/// CPU milliseconds per frame: `cpu_s` seconds over `frames`.
fn cpu_ms_per_frame(cpu_s: f64, frames: u64) -> f64 {
    if frames == 0 { 0.0 } else { cpu_s * 1e3 / frames as f64 }
}

/// Robots at `frame_rate` that `cores` serve at `cpu_ms` CPU milliseconds a
/// frame, with nothing else to do.
fn compute_bound(cpu_ms: f64, frame_rate: f64, cores: f64) -> f64 {
    if cpu_ms <= 0.0 || frame_rate <= 0.0 { 0.0 } else { cores / (cpu_ms * 1e-3 * frame_rate) }
}

/// Cores this process may run on.
fn cores() -> f64 {
    std::thread::available_parallelism().map_or(1.0, |n| n.get() as f64)
}

/// A run that answered no control cycle while a mission drove a robot has
/// no figure to report: a p50 of 0 ms would read as perfect.
fn measured(robots: &RobotsSummary, missions_started: u64, load: &str) -> anyhow::Result<()> {
    anyhow::ensure!(
        robots.cycles > 0,
        "no control cycle was answered while a mission drove a robot in {:.0} s ({} frames sent, {} never \
         answered, {missions_started} missions started): the stack cannot keep up with {load}, or no mission \
         started in time (try a longer --warmup or fewer robots)",
        robots.seconds,
        robots.frames_sent,
        robots.unanswered + robots.dropped_at_edge,
    );
    Ok(())
}

/// `vlnav bench fleet`: one run, or one per count of `--sweep`.
pub async fn fleet(args: &FleetArgs, out: &mut impl std::io::Write) -> anyhow::Result<Vec<FleetReport>> {
    let counts = if args.sweep.is_empty() { vec![args.robots] } else { args.sweep.clone() };
    let mut reports = Vec::new();
    let sweep = counts.len() > 1;
    for n in counts {
        let report = match fleet_run(args, n).await {
            Ok(r) => r,
            // One count that cannot be measured does not end a sweep; it is reported.
            Err(e) if sweep => FleetReport {
                robots: n,
                perception: args.perception.as_str().into(),
                width: args.width,
                height: args.height,
                frame_rate: args.frame_rate,
                phases: args.phases.as_str().into(),
                depth_codec: args.link.depth_name(),
                colour_codec: args.link.colour_name(),
                error: Some(format!("{e:#}")),
                ..Default::default()
            },
            Err(e) => return Err(e),
        };
        if args.json {
            writeln!(out, "{}", serde_json::to_string(&report)?)?;
        } else {
            writeln!(out, "{report}\n")?;
        }
        out.flush()?;
        reports.push(report);
    }
    let failed = reports.iter().filter(|r| r.error.is_some()).count();
    anyhow::ensure!(failed == 0, "{failed} of {} runs could not be measured (see above)", reports.len());
    Ok(reports)
}

/// `vlnav bench plot`: p50 (dashed) and p99 (solid) cycle latency against
/// the number of robots, log–log, one colour per series, the goal as a line.
pub fn plot(args: &PlotArgs) -> anyhow::Result<()> {
    let mut series = Vec::new();
    for path in &args.series {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
        let mut runs: Vec<FleetReport> = text
            .lines()
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                serde_json::from_str(l).with_context(|| format!("{}: not a bench fleet --json line", path.display()))
            })
            .collect::<anyhow::Result<_>>()?;
        anyhow::ensure!(!runs.is_empty(), "{} holds no runs", path.display());
        // A run without a measured cycle (no frame answered while driving) has no point to draw.
        runs.retain(|r| r.error.is_none() && r.cycles > 0);
        anyhow::ensure!(!runs.is_empty(), "{} holds no measured runs", path.display());
        runs.sort_by_key(|r| r.robots);
        series.push(runs);
    }
    let svg = plot_svg(&series, args.goal_ms);
    std::fs::write(&args.out, svg).with_context(|| format!("cannot write {}", args.out.display()))?;
    Ok(())
}

fn series_label(runs: &[FleetReport]) -> String {
    let r = &runs[0];
    let colour = if r.colour_codec.is_empty() { "raw" } else { r.colour_codec.as_str() };
    format!(
        "{} perception, {}x{}, {colour} colour, {} depth{}{}{}",
        r.perception,
        r.width,
        r.height,
        r.depth_codec,
        if r.load.starts_with("replayed") { ", replayed robots" } else { "" },
        if r.phases == "random" { ", random phases" } else { "" },
        if r.flood.is_some() { ", SubmitMission flood" } else { "" }
    )
}

fn plot_svg(series: &[Vec<FleetReport>], goal_ms: f64) -> String {
    use std::fmt::Write;
    // Room below the axes for one legend line per series.
    let bottom = (46.0 + 16.0 * series.len() as f64).max(110.0);
    let (w, h, left, right, top) = (720.0, 330.0 + bottom, 70.0, 20.0, 30.0);
    let (pw, ph) = (w - left - right, h - top - bottom);
    let all = series.iter().flatten();
    let max_n = all.clone().map(|r| r.robots).max().unwrap_or(1).max(2) as f64;
    let max_ms = all.clone().map(|r| r.cycle_p99_ms).fold(goal_ms, f64::max) * 1.5;
    let min_ms = all.map(|r| r.cycle_p50_ms).filter(|v| *v > 0.0).fold(goal_ms, f64::min) / 1.5;
    let x = |n: f64| left + pw * n.max(1.0).log10() / max_n.log10();
    let y = |ms: f64| top + ph * (1.0 - (ms.max(min_ms).log10() - min_ms.log10()) / (max_ms.log10() - min_ms.log10()));
    let colours = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e"];
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12"><rect width="100%" height="100%" fill="white"/>"#
    );
    let _ = write!(
        s,
        r#"<text x="{}" y="18" text-anchor="middle" font-size="14">Control cycle (frame in → command out) against robots on one gateway</text>"#,
        w / 2.0
    );
    // Axes, ticks, grid.
    let _ = write!(s, r#"<path d="M{left},{top} V{} H{}" stroke="black" fill="none"/>"#, top + ph, left + pw);
    for n in [1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0] {
        if n > max_n * 1.01 {
            break;
        }
        let _ = write!(
            s,
            r##"<path d="M{0},{1} V{2}" stroke="#ddd"/><text x="{0}" y="{3}" text-anchor="middle">{4}</text>"##,
            x(n),
            top,
            top + ph,
            top + ph + 16.0,
            n
        );
    }
    let mut tick = 10f64.powf(min_ms.log10().floor());
    while tick <= max_ms {
        for m in [1.0, 2.0, 5.0] {
            let v = tick * m;
            if v >= min_ms && v <= max_ms {
                let _ = write!(
                    s,
                    r##"<path d="M{left},{0} H{1}" stroke="#ddd"/><text x="{2}" y="{3}" text-anchor="end">{4}</text>"##,
                    y(v),
                    left + pw,
                    left - 6.0,
                    y(v) + 4.0,
                    v
                );
            }
        }
        tick *= 10.0;
    }
    let _ = write!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">robots (10 Hz each)</text><text transform="translate(18,{}) rotate(-90)" text-anchor="middle">milliseconds</text>"#,
        left + pw / 2.0,
        top + ph + 34.0,
        top + ph / 2.0
    );
    let _ = write!(
        s,
        r##"<path d="M{left},{0} H{1}" stroke="#888" stroke-dasharray="2,3"/><text x="{2}" y="{3}" text-anchor="end" fill="#666">goal: p99 ≤ {goal_ms} ms</text>"##,
        y(goal_ms),
        left + pw,
        left + pw - 4.0,
        y(goal_ms) - 4.0
    );
    for (i, runs) in series.iter().enumerate() {
        let c = colours[i % colours.len()];
        let path = |f: &dyn Fn(&FleetReport) -> f64| {
            runs.iter()
                .enumerate()
                .map(|(k, r)| format!("{}{:.1},{:.1}", if k == 0 { "M" } else { " L" }, x(r.robots as f64), y(f(r))))
                .collect::<String>()
        };
        let _ = write!(s, r#"<path d="{}" stroke="{c}" stroke-width="2" fill="none"/>"#, path(&|r| r.cycle_p99_ms));
        let _ = write!(
            s,
            r#"<path d="{}" stroke="{c}" stroke-width="1.5" stroke-dasharray="6,4" fill="none"/>"#,
            path(&|r| r.cycle_p50_ms)
        );
        for r in runs {
            let _ =
                write!(s, r#"<circle cx="{:.1}" cy="{:.1}" r="3" fill="{c}"/>"#, x(r.robots as f64), y(r.cycle_p99_ms));
        }
        let ly = top + ph + 56.0 + i as f64 * 16.0;
        let _ = write!(
            s,
            r#"<path d="M{left},{0} h24" stroke="{c}" stroke-width="2"/><text x="{1}" y="{2}">{3}: p99 solid, p50 dashed</text>"#,
            ly - 4.0,
            left + 30.0,
            ly,
            series_label(runs)
        );
    }
    s.push_str("</svg>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_that_answered_no_cycle_is_an_error_not_a_zero() {
        let none = RobotsSummary { seconds: 20.0, frames_sent: 2000, unanswered: 1990, ..Default::default() };
        let e = measured(&none, 0, "100 robots at 640x480 and 10 fps").unwrap_err().to_string();
        assert!(e.contains("no control cycle") && e.contains("1990 never answered") && e.contains("100 robots"), "{e}");
        let some = RobotsSummary { cycles: 1, ..none };
        assert!(measured(&some, 1, "1 robot").is_ok());
    }

    fn at(base: Instant, ms: u64) -> Instant {
        base + Duration::from_millis(ms)
    }

    #[test]
    fn cycles_pair_each_command_with_its_frame_and_count_what_was_passed_over() {
        let t = Instant::now();
        let mut s = CycleStats::default();
        s.on(LinkEvent::Frame { stamp: 0.1, queued: true, at: at(t, 0), bytes: 1000, image_bytes: 800 }, true, 0.1);
        s.on(LinkEvent::Command { stamp: 0.1, idle: false, at: at(t, 12) }, true, 0.1);
        // Frame 0.2 is passed over by the gateway; 0.3 is answered late.
        s.on(LinkEvent::Frame { stamp: 0.2, queued: true, at: at(t, 100), bytes: 1000, image_bytes: 800 }, true, 0.1);
        s.on(LinkEvent::Frame { stamp: 0.3, queued: true, at: at(t, 200), bytes: 1000, image_bytes: 800 }, true, 0.1);
        s.on(LinkEvent::Command { stamp: 0.3, idle: false, at: at(t, 350) }, true, 0.1);
        // The robot's queue was full; an idle answer is not a mission cycle.
        s.on(LinkEvent::Frame { stamp: 0.4, queued: false, at: at(t, 300), bytes: 1000, image_bytes: 800 }, true, 0.1);
        s.on(LinkEvent::Frame { stamp: 0.5, queued: true, at: at(t, 400), bytes: 1000, image_bytes: 800 }, true, 0.1);
        s.on(LinkEvent::Command { stamp: 0.5, idle: true, at: at(t, 401) }, true, 0.1);
        // A command for a frame nobody recorded changes nothing.
        s.on(LinkEvent::Command { stamp: 0.45, idle: false, at: at(t, 402) }, true, 0.1);
        assert_eq!(s.sent, 5);
        // The frame dropped at the robot never reached the link.
        assert_eq!((s.bytes, s.image_bytes), (4000, 3200));
        assert_eq!((s.dropped_at_edge, s.unanswered, s.idle, s.late), (1, 1, 1, 1));
        assert_eq!(s.cycles_ms.len(), 2);
        assert!((s.cycles_ms[0] - 12.0).abs() < 1.0 && (s.cycles_ms[1] - 150.0).abs() < 1.0, "{:?}", s.cycles_ms);
    }

    #[test]
    fn nothing_is_counted_outside_the_measurement() {
        let t = Instant::now();
        let mut s = CycleStats::default();
        s.on(LinkEvent::Frame { stamp: 1.0, queued: true, at: t, bytes: 10, image_bytes: 5 }, false, 0.1);
        s.on(LinkEvent::Frame { stamp: 1.1, queued: true, at: t, bytes: 10, image_bytes: 5 }, false, 0.1);
        s.on(LinkEvent::Command { stamp: 1.1, idle: false, at: t }, false, 0.1);
        assert_eq!((s.sent, s.unanswered, s.cycles_ms.len(), s.bytes), (0, 0, 0, 0));
        assert!(s.pending.is_empty());
    }

    #[test]
    fn a_frame_sent_before_the_measurement_is_not_counted_when_answered_during_it() {
        let t = Instant::now();
        let mut s = CycleStats::default();
        s.on(LinkEvent::Frame { stamp: 1.0, queued: true, at: t, bytes: 10, image_bytes: 5 }, false, 0.1);
        s.on(LinkEvent::Frame { stamp: 1.1, queued: true, at: t, bytes: 10, image_bytes: 5 }, true, 0.1);
        s.on(LinkEvent::Command { stamp: 1.0, idle: false, at: t }, true, 0.1);
        s.on(LinkEvent::Command { stamp: 1.1, idle: false, at: t }, true, 0.1);
        assert_eq!((s.sent, s.cycles_ms.len()), (1, 1));
    }

    #[test]
    fn the_uplink_is_megabits_per_second_per_robot() {
        // 10 frames of 125,000 bytes a second is 10 Mbit/s; two robots share what was summed.
        assert!((mbit_s_per_robot(2 * 10 * 125_000 * 30, 2, 30.0) - 10.0).abs() < 1e-9);
        assert_eq!(mbit_s_per_robot(1000, 0, 1.0), 0.0);
        assert_eq!(mbit_s_per_robot(1000, 1, 0.0), 0.0);
    }

    #[test]
    fn the_compute_bound_is_cores_over_the_cpu_a_second_of_frames_takes() {
        // 20 ms of CPU a frame at 10 fps is a fifth of a core per robot.
        assert_eq!(cpu_ms_per_frame(4.0, 200), 20.0);
        assert!((compute_bound(20.0, 10.0, 2.0) - 10.0).abs() < 1e-9);
        assert_eq!(cpu_ms_per_frame(1.0, 0), 0.0, "no frame: no figure");
        assert_eq!(compute_bound(0.0, 10.0, 2.0), 0.0);
    }

    #[test]
    fn quantiles_are_the_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&v, 0.5), 50.0);
        assert_eq!(quantile(&v, 0.99), 99.0);
        assert_eq!(quantile(&v, 1.0), 100.0);
        assert_eq!(quantile(&[], 0.5), 0.0);
    }

    #[test]
    fn this_process_reports_cpu_and_memory() {
        let (cpu, rss) = proc_usage(std::process::id()).unwrap();
        assert!(cpu >= 0.0 && rss > 1.0, "cpu {cpu} s, rss {rss} MiB");
        let threads = thread_usage(std::process::id());
        assert!(!threads.is_empty());
    }

    #[test]
    fn the_busiest_threads_are_summed_by_name() {
        let at = |v: &[(u32, &str, f64)]| v.iter().map(|(t, n, c)| (*t, (n.to_string(), *c))).collect();
        let before = at(&[(1, "worker", 1.0), (2, "worker", 1.0), (3, "segmenter-actor", 0.0)]);
        let after = at(&[(1, "worker", 2.0), (2, "worker", 1.5), (3, "segmenter-actor", 1.8), (4, "new", 0.001)]);
        let b = busiest(&before, &after, 2.0, 5);
        assert_eq!(b, vec![("segmenter-actor".to_string(), 90.0), ("worker".to_string(), 75.0)]);
    }

    #[test]
    fn the_plot_draws_every_series_and_the_goal() {
        let run = |n, p50, p99, perception: &str| FleetReport {
            robots: n,
            cycle_p50_ms: p50,
            cycle_p99_ms: p99,
            perception: perception.into(),
            width: 640,
            height: 480,
            depth_codec: "rvl".into(),
            colour_codec: "jpeg q85".into(),
            ..Default::default()
        };
        let a = vec![run(1, 5.0, 9.0, "oracle"), run(10, 6.0, 20.0, "oracle"), run(100, 80.0, 900.0, "oracle")];
        let b = vec![run(1, 8.0, 15.0, "realistic"), run(10, 12.0, 60.0, "realistic")];
        let svg = plot_svg(&[a, b], 50.0);
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(svg.contains("oracle perception, 640x480, jpeg q85 colour, rvl depth"), "{svg}");
        assert!(svg.contains("realistic perception, 640x480"));
        assert!(svg.contains("goal: p99 ≤ 50 ms"));
        assert_eq!(svg.matches("<circle").count(), 5);
        assert!(!svg.contains("NaN") && !svg.contains("inf"));
    }

    #[test]
    fn random_phases_spread_the_robots_over_the_period_and_aligned_ones_do_not() {
        let shares: Vec<f64> = (0..1000).map(|i| Phases::Random.delay_share(i)).collect();
        assert!(shares.iter().all(|s| (0.0..1.0).contains(s)));
        // Each tenth of the period holds about a tenth of the robots.
        for k in 0..10 {
            let n = shares.iter().filter(|s| (k as f64 / 10.0..(k + 1) as f64 / 10.0).contains(*s)).count();
            assert!((70..=130).contains(&n), "tenth {k}: {n} robots");
        }
        assert_eq!(Phases::Random.delay_share(3), Phases::Random.delay_share(3), "the same robot, the same phase");
        assert!((0..10).all(|i| Phases::Aligned.delay_share(i) == 0.0));
    }
}
