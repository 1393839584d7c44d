//! Gateway settings: where the stage services are, where missions persist,
//! and the executor's parameters (docs/design.md §2, the authors' values by default).

use std::net::SocketAddr;
use std::path::PathBuf;

#[derive(clap::Args, Clone, Debug)]
pub struct GatewayOptions {
    #[arg(long, env = "VLNAV_INGRESS_ADDR", default_value = "http://127.0.0.1:50052")]
    pub ingress_uri: String,
    #[arg(long, env = "VLNAV_PLANNER_ADDR", default_value = "http://127.0.0.1:50053")]
    pub planner_uri: String,
    #[arg(long, env = "VLNAV_DETECTOR_ADDR", default_value = "http://127.0.0.1:50054")]
    pub detector_uri: String,
    #[arg(long, env = "VLNAV_REID_ADDR", default_value = "http://127.0.0.1:50055")]
    pub reid_uri: String,
    #[arg(long, env = "VLNAV_SEGMENTER_ADDR", default_value = "http://127.0.0.1:50056")]
    pub segmenter_uri: String,
    #[arg(long, env = "VLNAV_SUBGOAL_ADDR", default_value = "http://127.0.0.1:50057")]
    pub subgoal_uri: String,
    #[arg(long, env = "VLNAV_LOCAL_PLANNER_ADDR", default_value = "http://127.0.0.1:50058")]
    pub local_planner_uri: String,
    /// Where missions and their event logs persist.
    #[arg(long, env = "VLNAV_DATA_DIR", default_value = ".vlnav")]
    pub data_dir: PathBuf,
    /// Bearer tokens (TOML, hashed; docs/security.md), read again when the
    /// file changes. Without it every caller is anonymous.
    #[arg(long, env = "VLNAV_TOKENS_FILE")]
    pub tokens_file: Option<PathBuf>,
    /// How the gateway reaches the stage services over `https://`: the CA
    /// their certificates are verified against and the gateway's own certificate.
    #[command(flatten)]
    pub stage_tls: vlnav_runtime::security::ClientTlsArgs,
    #[command(flatten)]
    pub executor: ExecutorParams,
    /// Missions one caller may submit a minute (dry runs included); more get
    /// RESOURCE_EXHAUSTED. 0: no limit.
    #[arg(long, env = "VLNAV_SUBMIT_PER_MINUTE", default_value_t = 60)]
    pub submit_per_minute: u32,
    /// Submissions one caller may make at once before the per-minute rate applies.
    #[arg(long, env = "VLNAV_SUBMIT_BURST", default_value_t = 20)]
    pub submit_burst: u32,
    /// The live view and the mission recordings (docs/observability.md).
    #[command(flatten)]
    pub view: ViewOptions,
    /// How long the executor waits for one stage call, seconds of wall
    /// time: a stage that accepted a call and never answers (a stuck
    /// handler answers HTTP/2 pings, so keepalive never ends the call) is a
    /// failed stage after this, held and retried like a refused call
    /// (docs/architecture.md, "Overload").
    #[arg(long, env = "VLNAV_STAGE_TIMEOUT_S", default_value_t = DEFAULT_STAGE_TIMEOUT_S, value_parser = positive_seconds)]
    pub stage_timeout_s: f64,
}

/// `--stage-timeout-s` by default: as long as a stage may stay down before
/// its mission fails (`executor::machine::STAGE_OUTAGE_S`).
pub(crate) const DEFAULT_STAGE_TIMEOUT_S: f64 = 10.0;

/// A duration in seconds that is finite and above zero.
fn positive_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 86_400.0 => Ok(v),
        _ => Err(format!("{s:?} is not a duration in seconds between 0 and 86400 (e.g. 10 or 2.5)")),
    }
}

/// Where the live view listens and what is recorded.
#[derive(clap::Args, Clone, Debug)]
pub struct ViewOptions {
    /// Where the live view (the Foxglove WebSocket protocol) listens, or
    /// `off`. The protocol carries no credentials, so an address other than
    /// loopback also needs --live-view-insecure; reach a remote gateway's
    /// view through `kubectl port-forward` or an SSH tunnel instead.
    #[arg(long, env = "VLNAV_LIVE_VIEW", default_value = "127.0.0.1:8765")]
    pub live_view: String,
    /// Serve the live view on a non-loopback address: anyone who reaches it
    /// sees every robot's camera.
    #[arg(long, env = "VLNAV_LIVE_VIEW_INSECURE")]
    pub live_view_insecure: bool,
    /// Record every mission (not dry runs) to MCAP in `<data-dir>/recordings`.
    #[arg(long, env = "VLNAV_RECORD", default_value_t = true, action = clap::ArgAction::Set)]
    pub record: bool,
    /// A recording continues in a new file once its file reaches this size, MiB.
    #[arg(long, env = "VLNAV_RECORD_MAX_MIB", default_value_t = 512, value_parser = clap::value_parser!(u64).range(1..))]
    pub record_max_mib: u64,
    /// The recordings directory is kept under this size, MiB: the oldest
    /// finished recordings are deleted when a mission starts (0: keep all).
    #[arg(long, env = "VLNAV_RECORD_BUDGET_MIB", default_value_t = 20480)]
    pub record_budget_mib: u64,
    /// Facts about the deployment written into every recording's
    /// `vlnav.mission` metadata (for example the perception mode a replay
    /// must use).
    #[arg(skip)]
    pub metadata: Vec<(String, String)>,
}

impl Default for ViewOptions {
    fn default() -> Self {
        Self {
            live_view: "127.0.0.1:8765".into(),
            live_view_insecure: false,
            record: true,
            record_max_mib: 512,
            record_budget_mib: 20480,
            metadata: Vec::new(),
        }
    }
}

impl ViewOptions {
    /// Neither a live view nor recordings.
    pub(crate) fn off() -> Self {
        Self { live_view: "off".into(), record: false, ..Self::default() }
    }

    /// The live view's address, checked; `None` when it is off.
    pub(crate) fn live_addr(&self) -> anyhow::Result<Option<SocketAddr>> {
        if self.live_view.eq_ignore_ascii_case("off") || self.live_view.is_empty() {
            return Ok(None);
        }
        let addr: SocketAddr = self.live_view.parse().map_err(|e| {
            anyhow::anyhow!("--live-view '{}' is not an address like 127.0.0.1:8765 or `off`: {e}", self.live_view)
        })?;
        if !addr.ip().is_loopback() && !self.live_view_insecure {
            anyhow::bail!(
                "refusing to serve the live view on {addr}: the Foxglove protocol carries no credentials, so anyone \
                 who reaches it would see every robot's camera. Keep it on loopback and reach it through \
                 `kubectl port-forward` or an SSH tunnel, or pass --live-view-insecure"
            );
        }
        Ok(Some(addr))
    }
}

/// Mission-executor parameters. Durations are sensor time.
#[derive(clap::Args, Clone, Debug)]
pub struct ExecutorParams {
    /// Sightings of the target (within the last --confirm-window frames)
    /// before it counts as found.
    #[arg(long, env = "VLNAV_CONFIRM_FRAMES", default_value_t = 3)]
    pub confirm_frames: u32,
    /// Frames the sightings are counted over (1–64; equal to --confirm-frames
    /// demands an unbroken streak).
    #[arg(long, env = "VLNAV_CONFIRM_WINDOW", default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub confirm_window: u32,
    /// Detector confidence for targets.
    #[arg(long, env = "VLNAV_MIN_SCORE", default_value_t = 0.4)]
    pub min_score: f32,
    /// Stopping distance of FIND/FOLLOW steps that give none, metres.
    #[arg(long, env = "VLNAV_DEFAULT_STOP_DISTANCE", default_value_t = 1.5)]
    pub default_d_s: f64,
    /// Frames without the target before exploring.
    #[arg(long, env = "VLNAV_UNSEEN_FRAMES", default_value_t = 10)]
    pub unseen_frames: u32,
    /// Rotation of one scan turn, radians (30°).
    #[arg(long, default_value_t = std::f64::consts::FRAC_PI_6)]
    pub scan_turn_rad: f64,
    /// Scan turns per full look-around.
    #[arg(long, default_value_t = 12)]
    pub scan_turns: u32,
    /// Frames to hold still and look after each scan turn.
    #[arg(long, default_value_t = 3)]
    pub look_frames: u32,
    /// Scan turns to each side of the way ahead in the look after a search
    /// leg (the way behind was looked at before the leg): the fan
    /// `+1 … +n, −1 … −n` scan turns off the leg's heading.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=6))]
    pub search_fan_turns: u32,
    /// Forward search legs after a fruitless look-around, before asking the
    /// user: a target too small to detect from here is looked for again
    /// from closer (docs/perception.md).
    #[arg(long, default_value_t = 4)]
    pub search_legs: u32,
    /// Length of one search leg, metres.
    #[arg(long, default_value_t = 4.0)]
    pub search_leg_m: f64,
    /// A step blocked (or making no progress) this long asks the user, seconds.
    #[arg(long, default_value_t = 8.0)]
    pub stuck_timeout_s: f64,
    /// A drive within its goal's tolerance + 0.25 m that has not got closer
    /// for this long settles where it is (it has arrived), seconds.
    #[arg(long, default_value_t = 3.0)]
    pub settle_after_s: f64,
    /// A drive that has not got 0.1 m closer for this long asks the user, seconds.
    #[arg(long, default_value_t = 30.0)]
    pub progress_timeout_s: f64,
    /// A step running longer than this asks the user, seconds.
    #[arg(long, default_value_t = 180.0)]
    pub step_timeout_s: f64,
    /// FOLLOW duration when the plan gives none, seconds.
    #[arg(long, default_value_t = 30.0)]
    pub follow_default_s: f64,
    /// A followed target unseen this long triggers exploration, seconds.
    #[arg(long, default_value_t = 3.0)]
    pub follow_lost_s: f64,
    /// Count a box as a sighting only if its height fits its class at the
    /// depth measured in it (a person 1.0–2.0 m, a chair 0.7–1.2 m, …;
    /// docs/perception.md). Off: on the development set it gained too
    /// little to tell from chance (docs/evaluation.md).
    #[arg(long, env = "VLNAV_SIZE_CHECK", default_value_t = false, action = clap::ArgAction::Set)]
    pub size_check: bool,
}

impl Default for ExecutorParams {
    fn default() -> Self {
        Self {
            confirm_frames: 3,
            confirm_window: 8,
            min_score: 0.4,
            default_d_s: 1.5,
            unseen_frames: 10,
            scan_turn_rad: std::f64::consts::FRAC_PI_6,
            scan_turns: 12,
            look_frames: 3,
            search_fan_turns: 2,
            search_legs: 4,
            search_leg_m: 4.0,
            stuck_timeout_s: 8.0,
            settle_after_s: 3.0,
            progress_timeout_s: 30.0,
            step_timeout_s: 180.0,
            follow_default_s: 30.0,
            follow_lost_s: 3.0,
            size_check: false,
        }
    }
}

impl ExecutorParams {
    /// The settings that differ from the defaults, as the flags that set
    /// them (`--scan-turns 6`): what an evaluation report says it ran with.
    pub fn changed_flags(&self) -> Vec<String> {
        let d = Self::default();
        // Destructured without `..`, so that a new setting cannot be left out.
        macro_rules! changed {
            ($($field:ident),*) => {{
                let Self { $($field),* } = self;
                let mut out = Vec::new();
                $(
                    if *$field != d.$field {
                        out.push(format!("--{} {}", stringify!($field).replace('_', "-"), $field));
                    }
                )*
                out
            }};
        }
        changed!(
            confirm_frames,
            confirm_window,
            min_score,
            default_d_s,
            unseen_frames,
            scan_turn_rad,
            scan_turns,
            look_frames,
            search_fan_turns,
            search_legs,
            search_leg_m,
            stuck_timeout_s,
            settle_after_s,
            progress_timeout_s,
            step_timeout_s,
            follow_default_s,
            follow_lost_s,
            size_check
        )
    }
}

impl GatewayOptions {
    /// Options pointing at services on loopback `ports`, data in `data_dir`.
    pub fn loopback(ports: &crate::config::StagePorts, data_dir: PathBuf) -> Self {
        let uri = |p: u16| format!("http://127.0.0.1:{p}");
        Self {
            ingress_uri: uri(ports.ingress),
            planner_uri: uri(ports.planner),
            detector_uri: uri(ports.detector),
            reid_uri: uri(ports.reid),
            segmenter_uri: uri(ports.segmenter),
            subgoal_uri: uri(ports.subgoal),
            local_planner_uri: uri(ports.local_planner),
            data_dir,
            tokens_file: None,
            stage_tls: Default::default(),
            executor: ExecutorParams::default(),
            view: ViewOptions::off(),
            submit_per_minute: 60,
            submit_burst: 20,
            stage_timeout_s: DEFAULT_STAGE_TIMEOUT_S,
        }
    }
}

impl GatewayOptions {
    /// The same services over `https://`, reached with `tls`.
    pub fn over_tls(mut self, tls: vlnav_runtime::security::ClientTlsArgs) -> Self {
        for uri in [
            &mut self.ingress_uri,
            &mut self.planner_uri,
            &mut self.detector_uri,
            &mut self.reid_uri,
            &mut self.segmenter_uri,
            &mut self.subgoal_uri,
            &mut self.local_planner_uri,
        ] {
            if let Some(rest) = uri.strip_prefix("http://") {
                *uri = format!("https://{rest}");
            }
        }
        self.stage_tls = tls;
        self
    }
}

/// Loopback ports of the stage services.
#[derive(Clone, Copy, Debug)]
pub struct StagePorts {
    /// The ingress (speech to text).
    pub ingress: u16,
    /// The planner.
    pub planner: u16,
    /// The detector.
    pub detector: u16,
    /// The ReID service.
    pub reid: u16,
    /// The segmenter.
    pub segmenter: u16,
    /// The subgoal estimator.
    pub subgoal: u16,
    /// The local planner.
    pub local_planner: u16,
}

impl Default for StagePorts {
    fn default() -> Self {
        use vlnav_runtime::ports;
        Self {
            ingress: ports::INGRESS,
            planner: ports::PLANNER,
            detector: ports::DETECTOR,
            reid: ports::REID,
            segmenter: ports::SEGMENTER,
            subgoal: ports::SUBGOAL,
            local_planner: ports::LOCAL_PLANNER,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::ExecutorParams;

    #[test]
    fn changed_executor_settings_are_named_by_their_flags() {
        assert!(ExecutorParams::default().changed_flags().is_empty(), "the defaults name nothing");
        let p = ExecutorParams { scan_turns: 6, search_leg_m: 5.5, ..Default::default() };
        assert_eq!(p.changed_flags(), vec!["--scan-turns 6", "--search-leg-m 5.5"]);
        // Each name is a flag the command line takes.
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            executor: ExecutorParams,
        }
        let args: Vec<String> = p.changed_flags().iter().flat_map(|f| f.split(' ').map(str::to_string)).collect();
        let parsed = <Cli as clap::Parser>::try_parse_from(std::iter::once("x".to_string()).chain(args)).unwrap();
        assert_eq!(parsed.executor.changed_flags(), p.changed_flags());
    }
}
