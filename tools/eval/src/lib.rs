//! vlnav-eval: the evaluation harness. It runs the paper's scenarios as
//! missions through the real services (lockstep simulation, gRPC end to end)
//! and reports the paper's metrics beside the paper's numbers.
//!
//! - [`metrics`]: per-trial definitions (success, stopping error, collisions);
//! - [`aggregate`]: one summary per (scenario, mode);
//! - [`report`]: Markdown and CSV tables with the paper's figures;
//! - [`plot`]: top-down SVG trajectory plots;
//! - [`suite`]: the scenario suite manifest and the trial plan;
//! - [`seed`]: reproducible per-trial seeds;
//! - [`paper`]: the paper's Tables IV and V;
//! - [`runner`]: one trial through a gateway (edge agent + MissionService);
//! - [`calibrate`]: `vlnav calibrate-perception`, the perception error model
//!   measured on the real detector and ReID embedder;
//! - [`jpeg_cost`]: `vlnav bench jpeg`, what JPEG colour on the robot's
//!   uplink costs the detector and the segmenter;
//! - [`worlds`]: `vlnav worlds generate`, seeded worlds of six families with
//!   instructions checked feasible on the true map.
//!
//! The gateway's `vlnav eval` parses [`EvalArgs`] and calls [`run_eval`]
//! with the URI of a running gateway (the all-in-one stack).

pub mod aggregate;
pub mod calibrate;
pub mod jpeg_cost;
pub mod metrics;
pub mod paper;
pub mod plot;
pub mod report;
pub mod runner;
pub mod seed;
pub mod suite;
pub mod worlds;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use futures::StreamExt;

use vlnav_edge_agent::{Codecs, ColourCodec, DepthCodec};
pub use vlnav_runtime::perception::PerceptionMode;

use crate::aggregate::Summary;
use crate::metrics::{Mode, TrialRecord};
use crate::report::ScenarioRef;
use crate::runner::{RunContext, TrialSettings};
use crate::suite::Suite;

/// The suite shipped in this crate, relative to the repository root.
pub const DEFAULT_SUITE: &str = "tools/eval/scenarios/suite.toml";

/// `vlnav eval` settings (flags or `VLNAV_EVAL_*` environment variables).
#[derive(clap::Args, Clone, Debug)]
pub struct EvalArgs {
    /// The suite manifest (scenarios, instructions, destinations).
    #[arg(long, env = "VLNAV_EVAL_SUITE", default_value = DEFAULT_SUITE)]
    pub suite: PathBuf,
    /// Trials per scenario and mode (default: the suite's, 50).
    #[arg(long, env = "VLNAV_EVAL_TRIALS")]
    pub trials: Option<u32>,
    /// Master seed: every trial's seed is hash(seed, scenario, mode, trial).
    #[arg(long, env = "VLNAV_EVAL_SEED", default_value_t = 1)]
    pub seed: u64,
    /// Run only these trial numbers of each scenario and mode (comma-separated,
    /// each below --trials), with the seeds they have in the full run: one
    /// row of a trials.csv, re-run alone to look at it.
    #[arg(long = "trial", value_delimiter = ',')]
    pub only_trials: Vec<u32>,
    /// Run only these scenarios (comma-separated names; default all).
    #[arg(long = "scenario", env = "VLNAV_EVAL_SCENARIOS", value_delimiter = ',')]
    pub scenarios: Vec<String>,
    /// Run only these modes: geometric, visual, hybrid (default all the suite has).
    #[arg(long = "mode", env = "VLNAV_EVAL_MODES", value_delimiter = ',')]
    pub modes: Vec<Mode>,
    /// Where the report, the CSV files and the plots are written.
    #[arg(long, env = "VLNAV_EVAL_OUT", default_value = ".vlnav/eval")]
    pub out: PathBuf,
    /// Trials run at once, each its own robot id. A lockstep trial waits on
    /// gRPC round trips most of the time, so many more than the cores pay.
    #[arg(long, env = "VLNAV_EVAL_JOBS", default_value_t = 16)]
    pub jobs: usize,
    /// Camera resolution of the simulated D455 (default: the suite's).
    #[arg(long, env = "VLNAV_EVAL_WIDTH")]
    pub width: Option<u32>,
    #[arg(long, env = "VLNAV_EVAL_HEIGHT")]
    pub height: Option<u32>,
    /// Frames per second of sensor time (the paper's camera ran at 5).
    #[arg(long, env = "VLNAV_EVAL_FRAME_RATE", default_value_t = 5.0)]
    pub frame_rate: f64,
    /// Trials plotted per scenario and mode (the first ones).
    #[arg(long, env = "VLNAV_EVAL_PLOTS", default_value_t = 1)]
    pub plots: u32,
    /// Wall-clock seconds a trial may make no progress before it counts as an error.
    #[arg(long, env = "VLNAV_EVAL_STALL_TIMEOUT_S", default_value_t = 60.0)]
    pub stall_timeout_s: f64,
    /// No progress bar.
    #[arg(long, env = "VLNAV_EVAL_NO_PROGRESS", default_value_t = false)]
    pub no_progress: bool,
    /// Perception of the stack the trials run on: `realistic` (the measured
    /// detector and ReID error model, the real segmenter), `oracle` (ground
    /// truth, an upper bound) or `neural` (the real networks; slow on CPU).
    #[arg(long, env = "VLNAV_PERCEPTION", value_enum, default_value_t = PerceptionMode::Realistic)]
    pub perception: PerceptionMode,
    /// The output directory of another run (its summary.csv and report.md),
    /// whose figures the tables show in brackets beside this run's: for
    /// example an `--perception oracle` run, the upper bound.
    #[arg(long, env = "VLNAV_EVAL_BESIDE")]
    pub beside: Option<PathBuf>,
    /// How the trial robots send their images: the evaluation over a
    /// compressed link.
    #[command(flatten)]
    pub link: Codecs,
    /// The stack's mission-executor settings that differ from the defaults,
    /// as flags (`--scan-turns 6`), named in the report (set by `vlnav eval`).
    #[arg(skip)]
    pub executor_flags: Vec<String>,
}

impl EvalArgs {
    /// The perception as the report names it, with the robot link's codecs
    /// when they are not raw.
    fn perception_label(&self) -> String {
        let mut parts = Vec::new();
        if self.link.colour != ColourCodec::Raw {
            parts.push(format!("{} colour", self.link.colour_name()));
        }
        if self.link.depth != DepthCodec::Raw {
            parts.push(format!("{} depth", self.link.depth_name()));
        }
        let mut label = if parts.is_empty() {
            self.perception.as_str().to_string()
        } else {
            format!("{}, robot link: {}", self.perception.as_str(), parts.join(", "))
        };
        if !self.executor_flags.is_empty() {
            label.push_str(&format!(", executor: {}", self.executor_flags.join(" ")));
        }
        label
    }
}

impl Default for EvalArgs {
    fn default() -> Self {
        Self {
            suite: PathBuf::from(DEFAULT_SUITE),
            trials: None,
            seed: 1,
            only_trials: Vec::new(),
            scenarios: Vec::new(),
            modes: Vec::new(),
            out: PathBuf::from(".vlnav/eval"),
            jobs: 16,
            width: None,
            height: None,
            frame_rate: 5.0,
            plots: 1,
            stall_timeout_s: 60.0,
            no_progress: false,
            perception: PerceptionMode::Realistic,
            beside: None,
            link: Codecs::default(),
            executor_flags: Vec::new(),
        }
    }
}

/// What a run produced.
#[derive(Debug)]
pub struct EvalReport {
    pub records: Vec<TrialRecord>,
    pub summaries: Vec<Summary>,
    /// The Markdown report (deterministic: no wall-clock figures).
    pub markdown: String,
    pub summary_csv: String,
    pub trials_csv: String,
    /// Files written: report.md, summary.csv, trials.csv, plots/*.svg and
    /// the plotted trials' tracks, plots/*.csv.
    pub out_dir: PathBuf,
    pub plots: Vec<PathBuf>,
    pub wall_s: f64,
    pub trials_run: usize,
}

impl EvalReport {
    /// Simulated sensor seconds per wall second over the whole run.
    pub fn speedup(&self) -> f64 {
        let sim: f64 = self.records.iter().map(|r| r.duration_s).sum();
        if self.wall_s > 0.0 { sim / self.wall_s } else { 0.0 }
    }
}

/// The suite file: as given, or — for the default relative path run from
/// elsewhere than the repository root — the copy beside this crate.
fn resolve_suite(path: &Path) -> PathBuf {
    if path.exists() || path != Path::new(DEFAULT_SUITE) {
        return path.to_path_buf();
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/suite.toml")
}

/// Writes `layout-<scenario>-<instruction>.svg` for every instruction of the
/// suite into `dir`: the world, the start, the destination and its success
/// circle, and the route's waypoints.
pub fn write_layouts(suite: &Suite, worlds: &[runner::LoadedWorld], dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut out = Vec::new();
    for (si, sc) in suite.scenarios.iter().enumerate() {
        for (ii, ins) in sc.instructions.iter().enumerate() {
            let scene = runner::layout_scene(suite, si, ii, &worlds[si].world);
            let path = dir.join(format!("layout-{}-{}.svg", sc.name, ins.id));
            std::fs::write(&path, plot::render_svg(&scene))
                .with_context(|| format!("cannot write {}", path.display()))?;
            out.push(path);
        }
    }
    Ok(out)
}

/// The gateway a suite runs against and how to reach it (docs/security.md).
#[derive(Clone, Debug)]
pub struct Target {
    pub gateway_uri: String,
    /// What the suite's mission client brings (CA, operator token).
    pub caller: vlnav_runtime::security::ClientSecurity,
    /// Issues each trial robot's certificate when the gateway wants them.
    pub pki: Option<vlnav_runtime::security::DevPki>,
}

impl Target {
    /// A plaintext gateway without tokens.
    pub fn plaintext(gateway_uri: String) -> Self {
        Self { gateway_uri, caller: Default::default(), pki: None }
    }
}

/// Runs the suite against `target` (whose stack runs `args.perception`,
/// which the report names) and writes the report.
pub async fn run_eval(args: EvalArgs, target: Target) -> anyhow::Result<EvalReport> {
    anyhow::ensure!(args.jobs >= 1, "--jobs must be at least 1");
    anyhow::ensure!(
        args.frame_rate.is_finite() && args.frame_rate > 0.0,
        "--frame-rate must be a positive number of frames per second"
    );
    anyhow::ensure!(
        args.stall_timeout_s.is_finite() && args.stall_timeout_s > 0.0,
        "--stall-timeout-s must be positive"
    );
    let suite_path = resolve_suite(&args.suite);
    let mut suite = Suite::load(&suite_path)?;
    suite.select(&args.scenarios).map_err(|e| anyhow::anyhow!("--scenario: {e}"))?;
    let trials = args.trials.unwrap_or(suite.run.trials);
    anyhow::ensure!(trials >= 1, "--trials must be at least 1");
    if let Some(t) = args.only_trials.iter().find(|&&t| t >= trials) {
        anyhow::bail!("--trial {t}: the run has trials 0 to {} (--trials {trials})", trials - 1);
    }
    let mut specs = suite::plan_trials(&suite, trials, args.seed, &args.modes);
    if !args.only_trials.is_empty() {
        specs.retain(|s| args.only_trials.contains(&s.trial));
    }
    anyhow::ensure!(!specs.is_empty(), "no trials to run: no scenario has instructions of the modes asked for");

    std::fs::create_dir_all(args.out.join("plots")).with_context(|| format!("cannot create {}", args.out.display()))?;
    let settings = TrialSettings {
        gateway_uri: target.gateway_uri,
        caller: target.caller,
        pki: target.pki,
        camera_width: args.width.unwrap_or(suite.run.camera_width),
        camera_height: args.height.unwrap_or(suite.run.camera_height),
        frame_rate_hz: args.frame_rate,
        stall_timeout_s: args.stall_timeout_s,
        work_dir: args.out.join("worlds"),
        codecs: args.link,
    };
    let refs = ScenarioRef::from_suite(&suite);
    let family_of: std::collections::BTreeMap<String, String> =
        suite.scenarios.iter().filter_map(|s| s.family.clone().map(|f| (s.name.clone(), f))).collect();
    let ctx = RunContext::new(suite, settings)?;
    let layouts = write_layouts(&ctx.suite, &ctx.worlds, &args.out.join("plots"))?;

    let bar = if args.no_progress {
        indicatif::ProgressBar::hidden()
    } else {
        let b =
            indicatif::ProgressBar::with_draw_target(Some(specs.len() as u64), indicatif::ProgressDrawTarget::stderr());
        b.set_style(
            indicatif::ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} trials, eta {eta} {msg}")
                .expect("a valid template")
                .progress_chars("=> "),
        );
        b
    };
    let started = Instant::now();
    let n_specs = specs.len();
    let plots_per_group = args.plots;
    let mut results = futures::stream::iter(specs.into_iter().map(|spec| {
        let ctx = ctx.clone();
        let with_plot = spec.trial < plots_per_group;
        tokio::spawn(runner::run_trial(ctx, spec, with_plot))
    }))
    .buffer_unordered(args.jobs);

    let mut records = Vec::with_capacity(n_specs);
    let mut plots = Vec::new();
    let mut successes = 0usize;
    while let Some(joined) = results.next().await {
        let result = joined.context("a trial task panicked")?;
        if result.record.success() {
            successes += 1;
        }
        if let Some(scene) = &result.plot {
            let r = &result.record;
            let path = args.out.join("plots").join(format!("{}-{}-{}.svg", r.scenario, r.mode, r.trial));
            std::fs::write(&path, plot::render_svg(scene))
                .with_context(|| format!("cannot write {}", path.display()))?;
            plots.push(path);
        }
        if let Some(track) = &result.track_csv {
            let r = &result.record;
            let path = args.out.join("plots").join(format!("{}-{}-{}.csv", r.scenario, r.mode, r.trial));
            std::fs::write(&path, track).with_context(|| format!("cannot write {}", path.display()))?;
            plots.push(path);
        }
        if result.record.outcome == metrics::Outcome::Error {
            bar.println(format!(
                "{} {} trial {}: error: {}",
                result.record.scenario, result.record.mode, result.record.trial, result.record.reason
            ));
        }
        records.push(result.record);
        bar.set_message(format!("{successes} succeeded"));
        bar.inc(1);
    }
    bar.finish();
    let wall_s = started.elapsed().as_secs_f64();
    plots.sort();
    plots.extend(layouts);

    let summaries = aggregate::summarise(&records);
    let beside = args.beside.as_deref().map(report::Beside::load).transpose()?;
    let mut markdown =
        report::markdown(&refs, &summaries, args.seed, trials, &args.perception_label(), beside.as_ref());
    // Generated worlds only: the shipped suite has no families, so its report is unchanged.
    if !family_of.is_empty() {
        markdown.push('\n');
        markdown.push_str(&report::family_markdown(&family_of, &records));
    }
    let summary_csv = report::summary_csv(&refs, &summaries)?;
    let trials_csv = report::trials_csv(&records)?;
    for (name, body) in [("report.md", &markdown), ("summary.csv", &summary_csv), ("trials.csv", &trials_csv)] {
        let path = args.out.join(name);
        std::fs::write(&path, body).with_context(|| format!("cannot write {}", path.display()))?;
    }
    let _ = std::fs::remove_dir(args.out.join("worlds"));
    Ok(EvalReport {
        records,
        summaries,
        markdown,
        summary_csv,
        trials_csv,
        out_dir: args.out,
        plots,
        wall_s,
        trials_run: n_specs,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        eval: EvalArgs,
    }

    #[test]
    fn flags_parse_into_eval_args() {
        let cli = Cli::try_parse_from([
            "vlnav-eval",
            "--mode",
            "visual,hybrid",
            "--scenario",
            "lab,corridor",
            "--trials",
            "3",
        ])
        .unwrap();
        assert_eq!(cli.eval.modes, vec![Mode::Visual, Mode::Hybrid]);
        assert_eq!(cli.eval.scenarios, vec!["lab".to_string(), "corridor".to_string()]);
        assert_eq!(cli.eval.trials, Some(3));
        assert_eq!(cli.eval.frame_rate, 5.0);
        assert_eq!(cli.eval.perception, PerceptionMode::Realistic, "realistic is the default");
        let e = Cli::try_parse_from(["vlnav-eval", "--mode", "sideways"]).err().unwrap().to_string();
        assert!(e.contains("geometric"), "{e}");
        let oracle = Cli::try_parse_from(["vlnav-eval", "--perception", "oracle"]).unwrap();
        assert_eq!(oracle.eval.perception, PerceptionMode::Oracle);
        let e = Cli::try_parse_from(["vlnav-eval", "--perception", "perfect"]).err().unwrap().to_string();
        for valid in ["oracle", "realistic", "neural"] {
            assert!(e.contains(valid), "the refusal names {valid}: {e}");
        }
    }

    #[test]
    fn the_robot_link_is_raw_unless_asked_and_a_compressed_one_is_named_in_the_report() {
        let cli = Cli::try_parse_from(["vlnav-eval"]).unwrap();
        assert_eq!(cli.eval.link, Codecs::default());
        assert_eq!(cli.eval.perception_label(), "realistic", "a raw link leaves the report as it was");
        let cli = Cli::try_parse_from([
            "vlnav-eval",
            "--colour-codec",
            "jpeg",
            "--depth-codec",
            "disparity",
            "--disparity-step",
            "0.01",
        ])
        .unwrap();
        assert_eq!(
            cli.eval.link,
            Codecs { colour: ColourCodec::Jpeg, jpeg_quality: 85, depth: DepthCodec::Disparity, disparity_step: 0.01 }
        );
        assert_eq!(cli.eval.perception_label(), "realistic, robot link: jpeg q85 colour, disparity 0.01/m depth");
        let executor = EvalArgs { executor_flags: vec!["--scan-turns 6".into()], ..cli.eval };
        assert_eq!(
            executor.perception_label(),
            "realistic, robot link: jpeg q85 colour, disparity 0.01/m depth, executor: --scan-turns 6"
        );
    }

    #[test]
    fn the_default_suite_is_found_from_any_directory() {
        let p = resolve_suite(Path::new(DEFAULT_SUITE));
        assert!(p.is_file(), "{}", p.display());
        assert_eq!(resolve_suite(Path::new("elsewhere.toml")), PathBuf::from("elsewhere.toml"));
    }
}
