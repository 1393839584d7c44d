//! The evaluation suite manifest (`scenarios/suite.toml`): which worlds to
//! run, the instructions given in each, where each instruction should take
//! the robot (for scoring), and how trials are drawn.
//!
//! The worlds themselves are the simulator's scenario files; everything the
//! simulator does not need — instructions, expected destinations, success
//! radii, the paper row a scenario stands for — lives here.
//!
//! ## Modes (Table IV)
//! Every instruction has a mode. A `hybrid` instruction is written as a
//! person would say it. The other two modes can be written by hand (`text`)
//! or derived from the instruction's `route`, the ordered waypoints the
//! mission passes through (world frame):
//! - `geometric`: dead reckoning only — each leg becomes "turn … degrees …
//!   and move … meters forward", computed from the scenario's *nominal* start
//!   pose, so start noise and wheel slip go uncorrected, as they would for a
//!   robot told only distances and angles;
//! - `visual`: only the legs that name a target, as "find the …" steps; legs
//!   without a landmark are dropped, so the robot must see its way there.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::metrics::{Mode, Point2, Pose, wrap_angle};
use crate::seed::{SplitMix64, trial_seed};

/// Run-wide defaults of the suite (each may be overridden on the command line
/// or, for the mission budget, per scenario).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RunDefaults {
    /// Trials per (scenario, mode).
    #[serde(default = "default_trials")]
    pub trials: u32,
    /// Rendered camera resolution for the evaluation, pixels.
    #[serde(default = "default_width")]
    pub camera_width: u32,
    #[serde(default = "default_height")]
    pub camera_height: u32,
    /// Uniform start-position noise, ± metres on x and y.
    #[serde(default = "default_noise_xy")]
    pub start_noise_xy_m: f64,
    /// Uniform start-heading noise, ± degrees.
    #[serde(default = "default_noise_theta")]
    pub start_noise_theta_deg: f64,
    /// Sensor-time budget of one mission, seconds.
    #[serde(default = "default_budget")]
    pub max_mission_s: f64,
}

fn default_trials() -> u32 {
    50
}
fn default_width() -> u32 {
    160
}
fn default_height() -> u32 {
    120
}
fn default_noise_xy() -> f64 {
    0.10
}
fn default_noise_theta() -> f64 {
    3.0
}
fn default_budget() -> f64 {
    180.0
}

impl Default for RunDefaults {
    fn default() -> Self {
        Self {
            trials: default_trials(),
            camera_width: default_width(),
            camera_height: default_height(),
            start_noise_xy_m: default_noise_xy(),
            start_noise_theta_deg: default_noise_theta(),
            max_mission_s: default_budget(),
        }
    }
}

/// One waypoint of an instruction's route, world frame.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Leg {
    /// Where this leg ends, metres.
    pub at: [f64; 2],
    /// The landmark at `at`, as spoken ("chair", "potted plant"); none for a
    /// purely geometric leg, which ends at `at`.
    #[serde(default)]
    pub find: Option<String>,
    /// Stopping distance from the landmark's near side, as spoken, metres.
    #[serde(default)]
    pub d_s: Option<f64>,
    /// The landmark's radius (half its footprint), metres: a leg with a
    /// landmark ends `d_s + size` short of `at` along the approach.
    #[serde(default)]
    pub size: f64,
}

impl Leg {
    /// Where the robot should stop at the end of this leg, coming from `from`.
    pub fn end_point(&self, from: Point2) -> Point2 {
        let at = Point2::new(self.at[0], self.at[1]);
        if self.find.is_none() {
            return at;
        }
        let short = self.d_s.unwrap_or(0.0) + self.size;
        let d = from.distance(at);
        if d <= short || d < 1e-9 {
            return from;
        }
        let k = (d - short) / d;
        Point2::new(from.x + (at.x - from.x) * k, from.y + (at.y - from.y) * k)
    }
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Instruction {
    pub id: String,
    pub mode: Mode,
    /// The instruction text; derived from `route` when absent (geometric and
    /// visual modes only).
    #[serde(default)]
    pub text: Option<String>,
    /// The ordered waypoints the mission passes through.
    #[serde(default)]
    pub route: Vec<Leg>,
    /// True destination G_d (world); defaults to the last waypoint.
    #[serde(default)]
    pub destination: Option<[f64; 2]>,
    /// Success radius around the destination, metres: the stopping
    /// distance plus a slack.
    pub radius: f64,
    /// Distance from the destination the instruction asks the robot to stop
    /// at (the spoken distance from the landmark's surface plus its half
    /// depth), metres; derived from the route's last leg when absent, 0 for
    /// a point destination.
    #[serde(default)]
    pub stop_m: Option<f64>,
    /// A walking pedestrian (its `name` in the world) the instruction
    /// follows: G_d is where that person is when the mission ends, not a
    /// fixed point (`destination` is then only the plots' marker).
    #[serde(default)]
    pub follow: Option<String>,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Short name used in seeds, file names and filters.
    pub name: String,
    /// Human-readable name for tables.
    pub title: String,
    /// The simulator's world file, relative to the suite file.
    pub world: PathBuf,
    /// Overrides the suite's start-position noise, ± metres.
    #[serde(default)]
    pub start_noise_xy_m: Option<f64>,
    /// Overrides the suite's start-heading noise, ± degrees (a symmetric room
    /// is one where the robot cannot tell which way it faces).
    #[serde(default)]
    pub start_noise_theta_deg: Option<f64>,
    /// The row of the paper's Table V this scenario stands in for.
    #[serde(default)]
    pub paper_table_v: Option<String>,
    /// The row of the paper's Table IV this scenario stands in for.
    #[serde(default)]
    pub paper_table_iv: Option<String>,
    /// Overrides the suite's mission budget, sensor seconds.
    #[serde(default)]
    pub max_mission_s: Option<f64>,
    /// The family of a generated world (`vlnav worlds generate`): the report
    /// adds a section per family when any scenario has one.
    #[serde(default)]
    pub family: Option<String>,
    #[serde(rename = "instruction")]
    pub instructions: Vec<Instruction>,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Suite {
    #[serde(default)]
    pub run: RunDefaults,
    #[serde(rename = "scenario")]
    pub scenarios: Vec<Scenario>,
    /// Directory the suite file lives in (world paths are relative to it).
    #[serde(skip)]
    pub base_dir: PathBuf,
}

#[derive(Debug, thiserror::Error)]
pub enum SuiteError {
    #[error("cannot read suite file {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("suite file {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("suite file {path}: {field}: {message}")]
    Invalid { path: PathBuf, field: String, message: String },
}

impl Scenario {
    /// Start noise of this scenario: (± metres, ± radians).
    pub fn start_noise(&self, run: &RunDefaults) -> (f64, f64) {
        (
            self.start_noise_xy_m.unwrap_or(run.start_noise_xy_m),
            self.start_noise_theta_deg.unwrap_or(run.start_noise_theta_deg).to_radians(),
        )
    }

    pub fn instructions_of(&self, mode: Mode) -> Vec<&Instruction> {
        self.instructions.iter().filter(|i| i.mode == mode).collect()
    }

    /// The modes this scenario has instructions for, in Table IV's order.
    pub fn modes(&self) -> Vec<Mode> {
        Mode::ALL.into_iter().filter(|m| self.instructions.iter().any(|i| i.mode == *m)).collect()
    }

    pub fn world_path(&self, suite: &Suite) -> PathBuf {
        suite.base_dir.join(&self.world)
    }
}

/// The slack a landmark destination's success radius adds to the stopping
/// distance (spoken distance + half depth), metres.
pub const LANDMARK_SLACK_M: f64 = 0.5;

impl Instruction {
    /// The distance from the destination the robot is asked to stop at:
    /// `stop_m` when the file gives it; for a route ending at a landmark, the
    /// leg's spoken distance plus the landmark's half size; for an explicit
    /// destination at a landmark's centre (a detectable object of `world`
    /// within 0.1 m), the radius less the suite's landmark slack
    /// ([`LANDMARK_SLACK_M`], the convention in `scenarios/suite.toml`'s
    /// header); otherwise 0 (a point destination).
    pub fn stop_distance(&self, world: &vlnav_sim::world::World) -> f64 {
        if let Some(d) = self.stop_m {
            return d;
        }
        match (self.route.last(), self.destination) {
            (Some(l), None) if l.find.is_some() => l.d_s.unwrap_or(0.0) + l.size,
            (_, Some(d)) => {
                let at = vlnav_sim::geometry::Vec2::new(d[0], d[1]);
                // Each class once: find_objects lists every instance of it.
                let classes: BTreeSet<i32> = world.entities.iter().map(|e| e.class_id).filter(|c| *c >= 0).collect();
                let landmark = classes
                    .into_iter()
                    .any(|c| world.find_objects(c, None, 0.0).iter().any(|(_, centre)| (*centre - at).norm() <= 0.1));
                if landmark { (self.radius - LANDMARK_SLACK_M).max(0.0) } else { 0.0 }
            }
            _ => 0.0,
        }
    }

    pub fn destination(&self) -> Point2 {
        let d = self.destination.or_else(|| self.route.last().map(|l| l.at)).unwrap_or([0.0, 0.0]);
        Point2::new(d[0], d[1])
    }

    /// The text submitted to the gateway. `start` is the scenario's nominal
    /// start pose (geometric derivation).
    pub fn text(&self, start: Pose) -> String {
        if let Some(t) = &self.text {
            return t.clone();
        }
        match self.mode {
            Mode::Geometric => geometric_text(start, &self.route),
            Mode::Visual => visual_text(&self.route),
            // Validation requires text for hybrid instructions.
            Mode::Hybrid => String::new(),
        }
    }
}

/// "turn left 90 degrees and move 4.0 meters forward, then …": the route as
/// dead-reckoned relative moves from `start`.
pub fn geometric_text(start: Pose, route: &[Leg]) -> String {
    let mut pose = start;
    let mut parts = Vec::new();
    for leg in route {
        let target = leg.end_point(pose.position().into());
        let dx = target.x - pose.x;
        let dy = target.y - pose.y;
        let dist = dx.hypot(dy);
        let heading = if dist > 1e-9 { dy.atan2(dx) } else { pose.theta };
        let turn_deg = wrap_angle(heading - pose.theta).to_degrees().round();
        let dist_r = (dist * 10.0).round() / 10.0;
        let turn = if turn_deg.abs() < 1.0 {
            None
        } else if turn_deg > 0.0 {
            Some(format!("turn left {} degrees", turn_deg as i64))
        } else {
            Some(format!("turn right {} degrees", (-turn_deg) as i64))
        };
        let part = match turn {
            Some(t) if dist_r >= 0.1 => format!("{t} and move {dist_r:.1} meters forward"),
            Some(t) => t,
            None => format!("move {dist_r:.1} meters forward"),
        };
        parts.push(part);
        pose = Pose::new(target.x, target.y, heading);
    }
    capitalise(&parts.join(", then "))
}

/// "find the chair, then find the potted plant": the route's landmarks only.
pub fn visual_text(route: &[Leg]) -> String {
    let parts: Vec<String> = route
        .iter()
        .filter_map(|l| l.find.as_ref().map(|t| (t, l.d_s)))
        .map(|(t, d_s)| match d_s {
            Some(d) => format!("stop {} before the {t}", metres(d)),
            None => format!("find the {t} and go close to it"),
        })
        .collect();
    capitalise(&parts.join(", then "))
}

fn metres(d: f64) -> String {
    let r = (d * 10.0).round() / 10.0;
    if (r - 1.0).abs() < 1e-9 {
        "1 meter".into()
    } else if r.fract() == 0.0 {
        format!("{r:.0} meters")
    } else {
        format!("{r:.1} meters")
    }
}

fn capitalise(s: &str) -> String {
    let mut c = s.chars();
    match c.next() {
        Some(first) => first.to_uppercase().collect::<String>() + c.as_str(),
        None => String::new(),
    }
}

impl Suite {
    pub fn load(path: &Path) -> Result<Suite, SuiteError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| SuiteError::Read { path: path.to_path_buf(), source })?;
        let base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Suite::parse(&text, path, base_dir)
    }

    /// Parses and validates a manifest; `path` only names the file in errors.
    pub fn parse(text: &str, path: &Path, base_dir: PathBuf) -> Result<Suite, SuiteError> {
        let mut suite: Suite =
            toml::from_str(text).map_err(|e| SuiteError::Parse { path: path.to_path_buf(), message: e.to_string() })?;
        suite.base_dir = base_dir;
        suite.validate(path)?;
        Ok(suite)
    }

    fn validate(&self, path: &Path) -> Result<(), SuiteError> {
        let invalid = |field: String, message: &str| SuiteError::Invalid {
            path: path.to_path_buf(),
            field,
            message: message.to_string(),
        };
        let r = &self.run;
        if r.camera_width < 16 || r.camera_height < 12 {
            return Err(invalid("run.camera_width/camera_height".into(), "must be at least 16 × 12 pixels"));
        }
        if !(r.start_noise_xy_m.is_finite() && r.start_noise_xy_m >= 0.0) {
            return Err(invalid("run.start_noise_xy_m".into(), "must be a finite number ≥ 0"));
        }
        if !(r.start_noise_theta_deg.is_finite() && r.start_noise_theta_deg >= 0.0) {
            return Err(invalid("run.start_noise_theta_deg".into(), "must be a finite number ≥ 0"));
        }
        if !(r.max_mission_s.is_finite() && r.max_mission_s > 0.0) {
            return Err(invalid("run.max_mission_s".into(), "must be a positive number of seconds"));
        }
        if self.scenarios.is_empty() {
            return Err(invalid("scenario".into(), "the suite has no [[scenario]]"));
        }
        let mut names = BTreeSet::new();
        for (si, s) in self.scenarios.iter().enumerate() {
            let at = |f: &str| format!("scenario[{si}] ({}).{f}", s.name);
            if s.name.is_empty() || !s.name.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_') {
                return Err(invalid(at("name"), "must be non-empty and use only letters, digits, '-' and '_'"));
            }
            if !names.insert(s.name.as_str()) {
                return Err(invalid(at("name"), "is used by another scenario"));
            }
            for (field, v) in
                [("start_noise_xy_m", s.start_noise_xy_m), ("start_noise_theta_deg", s.start_noise_theta_deg)]
            {
                if let Some(v) = v
                    && !(v.is_finite() && v >= 0.0)
                {
                    return Err(invalid(at(field), "must be a finite number ≥ 0"));
                }
            }
            if let Some(b) = s.max_mission_s
                && !(b.is_finite() && b > 0.0)
            {
                return Err(invalid(at("max_mission_s"), "must be a positive number of seconds"));
            }
            if let Some(v) = &s.paper_table_v
                && crate::paper::table_v(v).is_none()
            {
                return Err(invalid(at("paper_table_v"), "is not a row of the paper's Table V"));
            }
            if let Some(v) = &s.paper_table_iv
                && crate::paper::table_iv(v).is_none()
            {
                return Err(invalid(at("paper_table_iv"), "is not a row of the paper's Table IV"));
            }
            if s.instructions.is_empty() {
                return Err(invalid(at("instruction"), "the scenario has no [[scenario.instruction]]"));
            }
            let mut ids = BTreeSet::new();
            for (ii, ins) in s.instructions.iter().enumerate() {
                let at = |f: &str| format!("scenario[{si}] ({}).instruction[{ii}] ({}).{f}", s.name, ins.id);
                if ins.id.is_empty() || !ids.insert(ins.id.as_str()) {
                    return Err(invalid(at("id"), "must be non-empty and unique within the scenario"));
                }
                if !(ins.radius.is_finite() && ins.radius > 0.0) {
                    return Err(invalid(at("radius"), "must be a positive distance in metres"));
                }
                if let Some(d) = ins.stop_m
                    && !(d.is_finite() && d >= 0.0)
                {
                    return Err(invalid(at("stop_m"), "must be a distance in metres ≥ 0"));
                }
                if ins.stop_m.is_some_and(|d| d > ins.radius) {
                    return Err(invalid(at("stop_m"), "the stopping distance must lie within the success radius"));
                }
                if ins.route.iter().any(|l| !l.at.iter().all(|v| v.is_finite())) {
                    return Err(invalid(at("route.at"), "every waypoint must be two finite numbers [x_m, y_m]"));
                }
                if ins.route.iter().any(|l| l.d_s.is_some_and(|d| !(d.is_finite() && (0.0..=5.0).contains(&d)))) {
                    return Err(invalid(at("route.d_s"), "a stopping distance must be between 0 and 5 m"));
                }
                if ins.route.iter().any(|l| !(l.size.is_finite() && l.size >= 0.0)) {
                    return Err(invalid(at("route.size"), "must be a finite radius ≥ 0"));
                }
                if ins.follow.is_some() && ins.stop_m.is_none() {
                    return Err(invalid(
                        at("stop_m"),
                        "a followed person moves: give the distance to keep from their centre (d_s + body radius)",
                    ));
                }
                if ins.destination.is_none() && ins.route.is_empty() {
                    return Err(invalid(at("destination"), "give a destination or a route ending at it"));
                }
                match (&ins.text, ins.mode) {
                    (Some(t), _) if t.trim().is_empty() => {
                        return Err(invalid(at("text"), "must not be empty"));
                    }
                    (None, Mode::Hybrid) => {
                        return Err(invalid(at("text"), "a hybrid instruction needs its text written out"));
                    }
                    (None, Mode::Geometric) if ins.route.is_empty() => {
                        return Err(invalid(at("route"), "a geometric instruction without text needs a route"));
                    }
                    (None, Mode::Visual) if !ins.route.iter().any(|l| l.find.is_some()) => {
                        return Err(invalid(at("route"), "a visual instruction without text needs a leg with `find`"));
                    }
                    _ => {}
                }
            }
        }
        Ok(())
    }

    /// Keeps only the named scenarios (all when `names` is empty); an unknown
    /// name is an error that lists the known ones.
    pub fn select(&mut self, names: &[String]) -> Result<(), String> {
        if names.is_empty() {
            return Ok(());
        }
        for n in names {
            if !self.scenarios.iter().any(|s| &s.name == n) {
                let known: Vec<&str> = self.scenarios.iter().map(|s| s.name.as_str()).collect();
                return Err(format!("unknown scenario {n:?}; the suite has: {}", known.join(", ")));
            }
        }
        self.scenarios.retain(|s| names.contains(&s.name));
        Ok(())
    }

    pub fn scenario(&self, name: &str) -> Option<&Scenario> {
        self.scenarios.iter().find(|s| s.name == name)
    }
}

/// Everything that identifies one trial; all its randomness derives from `seed`.
#[derive(Clone, Debug, PartialEq)]
pub struct TrialSpec {
    pub scenario: usize,
    pub mode: Mode,
    /// Index into the scenario's instructions.
    pub instruction: usize,
    pub trial: u32,
    pub seed: u64,
    /// Start pose offset applied to the world's start pose, in the start
    /// pose's own frame (x forward, y left, heading).
    pub start_offset: Pose,
}

/// Start-pose noise of a trial, drawn from its seed.
pub fn start_offset(seed: u64, noise_xy_m: f64, noise_theta_rad: f64) -> Pose {
    // A stream of its own, so the simulator's slip stream (seeded with `seed`) is independent.
    let mut g = SplitMix64::new(seed ^ 0x5354_4152_545f_4e5a);
    Pose::new(g.symmetric(noise_xy_m), g.symmetric(noise_xy_m), g.symmetric(noise_theta_rad))
}

/// The suite's trials, in a fixed order: per scenario, per mode (Table IV's
/// order), trials 0…n−1; trial t of a mode runs that mode's instruction
/// t mod k. `modes` filters (all when empty).
pub fn plan_trials(suite: &Suite, trials: u32, master_seed: u64, modes: &[Mode]) -> Vec<TrialSpec> {
    let mut out = Vec::new();
    for (si, s) in suite.scenarios.iter().enumerate() {
        let noise = s.start_noise(&suite.run);
        for mode in s.modes() {
            if !modes.is_empty() && !modes.contains(&mode) {
                continue;
            }
            let of_mode: Vec<usize> =
                s.instructions.iter().enumerate().filter(|(_, i)| i.mode == mode).map(|(k, _)| k).collect();
            for t in 0..trials {
                let seed = trial_seed(master_seed, &s.name, mode.as_str(), t);
                out.push(TrialSpec {
                    scenario: si,
                    mode,
                    instruction: of_mode[t as usize % of_mode.len()],
                    trial: t,
                    seed,
                    start_offset: start_offset(seed, noise.0, noise.1),
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
[run]
trials = 4

[[scenario]]
name = "corridor"
title = "Featureless corridor"
world = "worlds/corridor.toml"
start_noise_theta_deg = 20
paper_table_iv = "Featureless Corridor"

[[scenario.instruction]]
id = "hybrid"
mode = "hybrid"
text = "Move 10 meters forward, then find the chair"
radius = 1.5
route = [{ at = [10.0, 0.0] }, { at = [12.0, 3.0], find = "chair" }]

[[scenario.instruction]]
id = "geo"
mode = "geometric"
radius = 1.5
route = [{ at = [10.0, 0.0] }, { at = [12.0, 3.0], find = "chair" }]

[[scenario.instruction]]
id = "vis"
mode = "visual"
radius = 1.5
route = [{ at = [10.0, 0.0] }, { at = [12.0, 3.0], find = "chair" }]
"#;

    fn parse(text: &str) -> Result<Suite, SuiteError> {
        Suite::parse(text, Path::new("suite.toml"), PathBuf::from("/suite"))
    }

    #[test]
    fn a_minimal_suite_parses_with_defaults() {
        let s = parse(MINIMAL).unwrap();
        assert_eq!(s.run.trials, 4);
        assert_eq!(s.run.camera_width, 160);
        let c = &s.scenarios[0];
        assert_eq!(c.modes(), vec![Mode::Geometric, Mode::Visual, Mode::Hybrid]);
        assert_eq!(c.world_path(&s), PathBuf::from("/suite/worlds/corridor.toml"));
        assert_eq!(c.instructions[0].destination(), Point2::new(12.0, 3.0));
    }

    #[test]
    fn stopping_distances_follow_the_suite_convention() {
        // Landmark destinations stop the radius less the 0.5 m slack from the
        // landmark's centre; point destinations at it; routes ending at a
        // landmark at d_s + size.
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/suite.toml");
        let suite = Suite::load(&path).unwrap();
        let stop = |scenario: &str, id: &str| {
            let sc = suite.scenarios.iter().find(|s| s.name == scenario).unwrap();
            let world = crate::runner::load_world(&sc.world_path(&suite)).unwrap().world;
            let ins = sc.instructions.iter().find(|i| i.id == id).unwrap();
            (ins.stop_distance(&world) * 100.0).round() / 100.0
        };
        assert_eq!(stop("indoor", "chair-then-plant"), 1.25);
        assert_eq!(stop("campus", "bench"), 2.3);
        assert_eq!(stop("garage", "motorcycle"), 2.5);
        assert_eq!(stop("forest", "hiker-then-clearing"), 0.0);
        assert_eq!(stop("corridor", "hybrid"), 0.0);
        let precise = suite.scenarios.iter().find(|s| s.name == "precise").unwrap();
        let leg = precise.instructions[0].route.last().unwrap();
        assert_eq!(stop("precise", "hybrid"), ((leg.d_s.unwrap_or(0.0) + leg.size) * 100.0).round() / 100.0);
    }

    #[test]
    fn derived_texts_follow_the_route() {
        let s = parse(MINIMAL).unwrap();
        let c = &s.scenarios[0];
        let start = Pose::new(0.0, 0.0, 0.0);
        assert_eq!(c.instructions[0].text(start), "Move 10 meters forward, then find the chair");
        // 10 m ahead, then atan2(3, 2) = 56.3° left of the current heading, 3.6 m.
        assert_eq!(
            c.instructions[1].text(start),
            "Move 10.0 meters forward, then turn left 56 degrees and move 3.6 meters forward"
        );
        assert_eq!(c.instructions[2].text(start), "Find the chair and go close to it");
    }

    #[test]
    fn the_planner_records_a_plan_for_every_suite_text() {
        // Every text the evaluation submits, written or derived from the
        // scenario's nominal start, has its plan recorded in the planner's
        // `tests/snapshots/suite_plans.tsv`, which the planner's `suite_plans`
        // test holds byte for byte. With VLNAV_BLESS set, missing texts are
        // appended with no plan; the planner's bless then records them.
        let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
        let suite = Suite::load(&manifest.join("scenarios/suite.toml")).unwrap();
        let snapshot = manifest.join("../../services/planner/tests/snapshots/suite_plans.tsv");
        let recorded = std::fs::read_to_string(&snapshot).unwrap_or_default();
        let known: BTreeSet<&str> = recorded.lines().filter_map(|l| l.split_once('\t').map(|(t, _)| t)).collect();
        let mut missing: Vec<String> = Vec::new();
        for sc in &suite.scenarios {
            let world = crate::runner::load_world(&sc.world_path(&suite)).unwrap().world;
            for ins in &sc.instructions {
                let text = ins.text(world.start);
                if !known.contains(text.as_str()) && !missing.contains(&text) {
                    missing.push(text);
                }
            }
        }
        if std::env::var_os("VLNAV_BLESS").is_some() && !missing.is_empty() {
            let mut out = recorded.clone();
            for t in &missing {
                out.push_str(&format!("{t}\t\n"));
            }
            std::fs::write(&snapshot, out).unwrap();
            return;
        }
        assert!(missing.is_empty(), "no recorded plan in {} for: {missing:#?}", snapshot.display());
    }

    #[test]
    fn geometric_turns_are_relative_to_the_current_heading() {
        let route = [
            Leg { at: [0.0, 5.0], find: None, d_s: None, size: 0.0 },
            Leg { at: [3.0, 5.0], find: None, d_s: None, size: 0.0 },
        ];
        let text = geometric_text(Pose::new(0.0, 0.0, 0.0), &route);
        assert_eq!(
            text,
            "Turn left 90 degrees and move 5.0 meters forward, then turn right 90 degrees and move 3.0 meters forward"
        );
        // Facing +y already: no turn first.
        let text = geometric_text(Pose::new(0.0, 0.0, std::f64::consts::FRAC_PI_2), &route[..1]);
        assert_eq!(text, "Move 5.0 meters forward");
    }

    #[test]
    fn landmark_legs_end_short_of_the_landmark() {
        let leg = Leg { at: [10.0, 0.0], find: Some("chair".into()), d_s: Some(1.0), size: 0.5 };
        let end = leg.end_point(Point2::new(0.0, 0.0));
        assert!((end.x - 8.5).abs() < 1e-12 && end.y.abs() < 1e-12);
        let route = [leg];
        assert_eq!(geometric_text(Pose::new(0.0, 0.0, 0.0), &route), "Move 8.5 meters forward");
        assert_eq!(visual_text(&route), "Stop 1 meter before the chair");
    }

    #[test]
    fn errors_name_the_field() {
        let bad = MINIMAL.replacen("radius = 1.5", "radius = -1", 1);
        let e = parse(&bad).unwrap_err().to_string();
        assert!(e.contains("instruction[0] (hybrid).radius"), "{e}");

        let bad = MINIMAL.replace("paper_table_iv = \"Featureless Corridor\"", "paper_table_iv = \"Corridor\"");
        let e = parse(&bad).unwrap_err().to_string();
        assert!(e.contains("paper_table_iv"), "{e}");

        let bad = MINIMAL.replacen("text = \"Move 10 meters forward, then find the chair\"\n", "", 1);
        let e = parse(&bad).unwrap_err().to_string();
        assert!(e.contains("hybrid instruction needs its text"), "{e}");

        let e = parse("[[scenario]]\nname = 'x'\n").unwrap_err().to_string();
        assert!(e.contains("missing field"), "{e}");

        let bad = MINIMAL.replace("trials = 4", "trials = 4\nbogus = 1");
        let e = parse(&bad).unwrap_err().to_string();
        assert!(e.contains("bogus"), "{e}");
    }

    #[test]
    fn scenario_names_must_be_unique() {
        let twice = format!("{MINIMAL}{}", &MINIMAL[MINIMAL.find("[[scenario]]").unwrap()..]);
        let e = parse(&twice).unwrap_err().to_string();
        assert!(e.contains("used by another scenario"), "{e}");
    }

    #[test]
    fn selecting_an_unknown_scenario_lists_the_known_ones() {
        let mut s = parse(MINIMAL).unwrap();
        let e = s.select(&["forest".into()]).unwrap_err();
        assert!(e.contains("corridor"), "{e}");
        s.select(&["corridor".into()]).unwrap();
        assert_eq!(s.scenarios.len(), 1);
    }

    #[test]
    fn the_trial_plan_is_reproducible_and_covers_every_mode() {
        let s = parse(MINIMAL).unwrap();
        let a = plan_trials(&s, 3, 99, &[]);
        let b = plan_trials(&s, 3, 99, &[]);
        assert_eq!(a, b);
        assert_eq!(a.len(), 9);
        assert_ne!(a, plan_trials(&s, 3, 100, &[]));
        assert!(a.iter().all(|t| s.scenarios[0].instructions[t.instruction].mode == t.mode));
        let only_visual = plan_trials(&s, 3, 99, &[Mode::Visual]);
        assert_eq!(only_visual.len(), 3);
        // Noise stays within the configured bounds (the scenario overrides the heading's).
        for t in &a {
            assert!(t.start_offset.x.abs() <= 0.10 && t.start_offset.y.abs() <= 0.10);
            assert!(t.start_offset.theta.abs() <= 20f64.to_radians() + 1e-12);
        }
        assert!(a.iter().any(|t| t.start_offset.theta.abs() > 3f64.to_radians()));
    }
}
