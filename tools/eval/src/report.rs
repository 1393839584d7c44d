//! Markdown and CSV tables, each beside the paper's numbers.
//!
//! Nothing here reads a clock: the same summaries render to the same bytes,
//! which is what the determinism check compares.

use std::fmt::Write as _;

use serde::Deserialize;

use crate::aggregate::Summary;
use crate::metrics::{Mode, TrialRecord};
use crate::paper;

/// What the tables need to know about a scenario besides its figures.
#[derive(Clone, Debug, PartialEq)]
pub struct ScenarioRef {
    pub name: String,
    pub title: String,
    pub paper_table_v: Option<String>,
    pub paper_table_iv: Option<String>,
}

impl ScenarioRef {
    pub fn from_suite(suite: &crate::suite::Suite) -> Vec<ScenarioRef> {
        suite
            .scenarios
            .iter()
            .map(|s| ScenarioRef {
                name: s.name.clone(),
                title: s.title.clone(),
                paper_table_v: s.paper_table_v.clone(),
                paper_table_iv: s.paper_table_iv.clone(),
            })
            .collect()
    }
}

fn find<'a>(summaries: &'a [Summary], scenario: &str, mode: Mode) -> Option<&'a Summary> {
    summaries.iter().find(|s| s.scenario == scenario && s.mode == mode)
}

/// "ours (paper)" for a cell, or "—" where the paper has no figure.
fn pair(ours: f64, paper: Option<f64>, decimals: usize) -> String {
    match paper {
        Some(p) => format!("{ours:.decimals$} ({p:.decimals$})"),
        None => format!("{ours:.decimals$} (—)"),
    }
}

/// "ours [beside] (paper)": `pair` with the other run's figure in brackets.
fn triple(ours: f64, beside: Option<Option<f64>>, paper: Option<f64>, decimals: usize) -> String {
    match beside {
        None => pair(ours, paper, decimals),
        Some(b) => {
            let b = b.map_or("—".to_string(), |b| format!("{b:.decimals$}"));
            let p = paper.map_or("—".to_string(), |p| format!("{p:.decimals$}"));
            format!("{ours:.decimals$} [{b}] ({p})")
        }
    }
}

/// Another run's figures per (scenario, mode), read back from its
/// `summary.csv`, shown in brackets beside this run's (`--beside`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Beside {
    /// What the other run was (its perception mode, from its report.md).
    pub label: String,
    rows: Vec<BesideRow>,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
struct BesideRow {
    scenario: String,
    mode: String,
    success_pct: f64,
    soft_trials_pct: f64,
    hard_trials_pct: f64,
    completed: u32,
    stop_abs_m: f64,
    stop_abs_std_m: f64,
}

impl Beside {
    /// Reads `dir/summary.csv` (and the perception named in `dir/report.md`).
    pub fn load(dir: &std::path::Path) -> anyhow::Result<Self> {
        use anyhow::Context;
        let path = dir.join("summary.csv");
        let text = std::fs::read_to_string(&path).with_context(|| {
            format!("--beside: cannot read {} (the output directory of another run)", path.display())
        })?;
        let mut rows = Vec::new();
        for row in csv::Reader::from_reader(text.as_bytes()).deserialize() {
            rows.push(row.with_context(|| format!("--beside: {} is not a vlnav eval summary", path.display()))?);
        }
        let label = std::fs::read_to_string(dir.join("report.md"))
            .ok()
            .and_then(|r| r.split('`').nth(1).map(str::to_string))
            .unwrap_or_else(|| dir.display().to_string());
        Ok(Self { label, rows })
    }

    fn row(&self, scenario: &str, mode: Mode) -> Option<&BesideRow> {
        self.rows.iter().find(|r| r.scenario == scenario && r.mode == mode.as_str())
    }

    fn stop(&self, scenario: &str, mode: Mode) -> String {
        self.row(scenario, mode).map_or("—".into(), |r| stop_cell(r.completed, r.stop_abs_m, r.stop_abs_std_m))
    }
}

fn slack_text(s: &Summary) -> String {
    let v: Vec<String> = s.slack_m.iter().map(|x| format!("{x:.2}")).collect();
    if v.is_empty() { "—".into() } else { v.join("/") }
}

/// Table V analogue: one row per scenario run in hybrid mode, every cell
/// "ours (paper)".
pub fn table_v_markdown(scenarios: &[ScenarioRef], summaries: &[Summary], beside: Option<&Beside>) -> String {
    let mut out = String::new();
    out.push_str(
        "| Environment (paper row) | Trials | Success % | Slack (m) | Success % at 0.25 m | Trials with soft collision % | Trials with hard collision % | Avg. path (m) | Stopping error (m) | Mission time (s) | Time in soft / hard contact % |\n",
    );
    out.push_str("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for sc in scenarios {
        let Some(s) = find(summaries, &sc.name, Mode::Hybrid) else { continue };
        let p = sc.paper_table_v.as_deref().and_then(paper::table_v);
        let row_name = match p {
            Some(p) => format!("{} ({})", sc.title, p.environment),
            None => sc.title.clone(),
        };
        let other = |f: fn(&BesideRow) -> f64| beside.map(|b| b.row(&sc.name, Mode::Hybrid).map(f));
        let stop_ours = match beside {
            Some(b) => format!("{} [{}]", stop_text(s), b.stop(&sc.name, Mode::Hybrid)),
            None => stop_text(s),
        };
        let stop = match p {
            Some(p) => format!("{stop_ours} ({:.2} ± {:.2})", p.drift_m, p.drift_std_m),
            None => format!("{stop_ours} (—)"),
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {:.1} | {} | {} | {} | {} | {:.1} | {:.1} / {:.1} |",
            row_name,
            s.trials,
            triple(s.success_pct, other(|r| r.success_pct), p.map(|p| p.success_pct), 1),
            slack_text(s),
            s.success_025_pct,
            triple(s.soft_trials_pct, other(|r| r.soft_trials_pct), p.map(|p| p.soft_collision_pct), 1),
            triple(s.hard_trials_pct, other(|r| r.hard_trials_pct), p.map(|p| p.hard_collision_pct), 1),
            pair(s.path_m, p.map(|p| p.path_m), 1),
            stop,
            s.mission_s,
            s.soft_time_pct,
            s.hard_time_pct,
        );
    }
    out
}

/// Table IV analogue: success % per mode, "ours (paper)".
pub fn table_iv_markdown(scenarios: &[ScenarioRef], summaries: &[Summary], beside: Option<&Beside>) -> String {
    let mut out = String::new();
    out.push_str("| Scenario (paper row) | Constraint | Geometric % | Visual % | Hybrid % |\n");
    out.push_str("|---|---|---:|---:|---:|\n");
    for sc in scenarios {
        let Some(key) = sc.paper_table_iv.as_deref() else { continue };
        let p = paper::table_iv(key);
        let cell = |mode: Mode| match find(summaries, &sc.name, mode) {
            Some(s) => triple(
                s.success_pct,
                beside.map(|b| b.row(&sc.name, mode).map(|r| r.success_pct)),
                p.map(|p| p.success_pct(mode)),
                1,
            ),
            None => match p {
                Some(p) => format!("not run ({:.1})", p.success_pct(mode)),
                None => "not run".into(),
            },
        };
        if !Mode::ALL.iter().any(|m| find(summaries, &sc.name, *m).is_some()) {
            continue;
        }
        let _ = writeln!(
            out,
            "| {} ({}) | {} | {} | {} | {} |",
            sc.title,
            key,
            p.map(|p| p.constraint).unwrap_or(""),
            cell(Mode::Geometric),
            cell(Mode::Visual),
            cell(Mode::Hybrid),
        );
    }
    out
}

/// Mean |stopping error| ± σ over the completed trials; "—" when none completed.
fn stop_text(s: &Summary) -> String {
    stop_cell(s.completed, s.stop_abs_m, s.stop_abs_std_m)
}

fn stop_cell(completed: u32, mean: f64, std: f64) -> String {
    if completed == 0 { "—".into() } else { format!("{mean:.2} ± {std:.2}") }
}

/// Every (scenario, mode) with every figure, ours only.
pub fn full_markdown(scenarios: &[ScenarioRef], summaries: &[Summary]) -> String {
    let mut out = String::new();
    out.push_str("| Scenario | Mode | Trials | Success % | Slack (m) | Success % at 0.25 m | Soft % trials | Hard % trials | Walked into % trials | Person contact % trials | Soft % time | Hard % time | Path (m) | Completed | Stopping error (m) | Bias (m) | Final error (m) | Time (s) | Frames | Failures |\n");
    out.push_str(
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
    );
    for sc in scenarios {
        for mode in Mode::ALL {
            let Some(s) = find(summaries, &sc.name, mode) else { continue };
            let failures: Vec<String> = s.failures.iter().map(|(k, v)| format!("{k} {v}")).collect();
            let _ = writeln!(
                out,
                "| {} | {} | {} | {:.1} | {} | {:.1} | {:.0} | {:.0} | {:.0} | {:.0} | {:.1} | {:.1} | {:.1} | {} | {} | {:+.2} | {:.2} | {:.1} | {} | {} |",
                sc.title,
                mode,
                s.trials,
                s.success_pct,
                slack_text(s),
                s.success_025_pct,
                s.soft_trials_pct,
                s.hard_trials_pct,
                s.walked_into_trials_pct,
                s.pedestrian_trials_pct,
                s.soft_time_pct,
                s.hard_time_pct,
                s.path_m,
                s.completed,
                stop_text(s),
                s.stop_bias_m,
                s.final_error_m,
                s.mission_s,
                s.frames,
                if failures.is_empty() { "—".into() } else { failures.join(", ") },
            );
        }
    }
    out
}

/// The whole Markdown report (no wall-clock figures: those go to the run log).
pub fn markdown(
    scenarios: &[ScenarioRef],
    summaries: &[Summary],
    master_seed: u64,
    trials: u32,
    perception: &str,
    beside: Option<&Beside>,
) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# vlnav evaluation\n");
    let _ = writeln!(
        out,
        "Perception `{perception}`, master seed {master_seed}, {trials} trials per scenario and mode. {}\n",
        match beside {
            Some(b) => format!("Cells read \"ours [the same with perception `{}`] (paper)\".", b.label),
            None => "Cells read \"ours (paper)\".".into(),
        }
    );
    let v = table_v_markdown(scenarios, summaries, beside);
    if v.lines().count() > 2 {
        let _ = writeln!(
            out,
            "## Table V — success, collisions, path and stopping error per environment (hybrid instructions)\n\n{v}"
        );
    }
    let iv = table_iv_markdown(scenarios, summaries, beside);
    if iv.lines().count() > 2 {
        let _ = writeln!(out, "## Table IV — success % per navigation modality\n\n{iv}");
    }
    let _ = writeln!(out, "## Every scenario and mode\n\n{}", full_markdown(scenarios, summaries));
    out.push_str(
        "Success: the mission ended SUCCEEDED with every step done, no hard contact, and the true final position \
within the success radius r of the true destination G_d; r is the asked stopping distance d plus the slack shown. \
Success at 0.25 m: the same with |stopping error| ≤ 0.25 m. Stopping error: ‖G_d − R_d‖ − d with no slack, \
mean |error| ± population standard deviation over the trials that completed every step (bias: the signed mean, \
positive = stopped farther than asked). Collisions: share of trials with at least one soft event (entered a no-go \
region) / hard event the robot made (it moved into structure, an object or a person), beside the paper's soft / \
hard collision %; a person walking into the stopped robot is counted apart and does not fail a trial. The share \
of mission time in contact is secondary. Time: sensor seconds.\n",
    );
    out
}

fn opt(v: Option<f64>) -> String {
    v.map(|v| format!("{v}")).unwrap_or_default()
}

/// One CSV row per (scenario, mode), our figures then the paper's.
pub fn summary_csv(scenarios: &[ScenarioRef], summaries: &[Summary]) -> anyhow::Result<String> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record([
        "scenario",
        "title",
        "mode",
        "trials",
        "successes",
        "success_pct",
        "slack_m",
        "success_025_pct",
        "soft_trials_pct",
        "hard_trials_pct",
        "walked_into_trials_pct",
        "pedestrian_trials_pct",
        "soft_time_pct",
        "hard_time_pct",
        "path_m",
        "completed",
        "stop_abs_m",
        "stop_abs_std_m",
        "stop_bias_m",
        "final_error_m",
        "mission_s",
        "frames",
        "paper_row",
        "paper_success_pct",
        "paper_soft_collision_pct",
        "paper_hard_collision_pct",
        "paper_path_m",
        "paper_drift_m",
    ])?;
    for sc in scenarios {
        for mode in Mode::ALL {
            let Some(s) = find(summaries, &sc.name, mode) else { continue };
            let pv = if mode == Mode::Hybrid { sc.paper_table_v.as_deref().and_then(paper::table_v) } else { None };
            let piv = sc.paper_table_iv.as_deref().and_then(paper::table_iv);
            let paper_row = pv.map(|p| p.environment).or(piv.map(|p| p.scenario)).unwrap_or("");
            let paper_success = pv.map(|p| p.success_pct).or(piv.map(|p| p.success_pct(mode)));
            w.write_record([
                s.scenario.clone(),
                sc.title.clone(),
                mode.to_string(),
                s.trials.to_string(),
                s.successes.to_string(),
                format!("{:.2}", s.success_pct),
                slack_text(s),
                format!("{:.2}", s.success_025_pct),
                format!("{:.2}", s.soft_trials_pct),
                format!("{:.2}", s.hard_trials_pct),
                format!("{:.2}", s.walked_into_trials_pct),
                format!("{:.2}", s.pedestrian_trials_pct),
                format!("{:.3}", s.soft_time_pct),
                format!("{:.3}", s.hard_time_pct),
                format!("{:.3}", s.path_m),
                s.completed.to_string(),
                format!("{:.4}", s.stop_abs_m),
                format!("{:.4}", s.stop_abs_std_m),
                format!("{:.4}", s.stop_bias_m),
                format!("{:.4}", s.final_error_m),
                format!("{:.2}", s.mission_s),
                s.frames.to_string(),
                paper_row.to_string(),
                opt(paper_success),
                opt(pv.map(|p| p.soft_collision_pct)),
                opt(pv.map(|p| p.hard_collision_pct)),
                opt(pv.map(|p| p.path_m)),
                opt(pv.map(|p| p.drift_m)),
            ])?;
        }
    }
    Ok(String::from_utf8(w.into_inner()?)?)
}

/// One CSV row per trial: everything needed to recompute every figure.
pub fn trials_csv(records: &[TrialRecord]) -> anyhow::Result<String> {
    let mut sorted: Vec<&TrialRecord> = records.iter().collect();
    sorted.sort_by(|a, b| (&a.scenario, a.mode, a.trial).cmp(&(&b.scenario, b.mode, b.trial)));
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record([
        "scenario",
        "mode",
        "trial",
        "seed",
        "instruction",
        "outcome",
        "success",
        "steps_completed",
        "steps_total",
        "destination_x",
        "destination_y",
        "success_radius_m",
        "stop_distance_m",
        "final_x",
        "final_y",
        "final_error_m",
        "stop_error_m",
        "success_025",
        "path_length_m",
        "odom_path_length_m",
        "duration_s",
        "frames",
        "replans",
        "soft_events",
        "hard_events",
        "soft_s",
        "hard_s",
        "hard_by_robot",
        "pedestrian_events",
        "pedestrian_by_robot",
        "reason",
    ])?;
    for r in sorted {
        w.write_record([
            r.scenario.clone(),
            r.mode.to_string(),
            r.trial.to_string(),
            r.seed.to_string(),
            r.instruction.clone(),
            r.outcome.as_str().to_string(),
            r.success().to_string(),
            r.steps_completed.to_string(),
            r.steps_total.to_string(),
            format!("{:.4}", r.destination.x),
            format!("{:.4}", r.destination.y),
            format!("{:.3}", r.success_radius_m),
            format!("{:.3}", r.stop_distance_m),
            format!("{:.4}", r.final_position.x),
            format!("{:.4}", r.final_position.y),
            format!("{:.4}", r.final_error_m()),
            format!("{:.4}", r.stop_error_m()),
            r.success_within(crate::aggregate::TIGHT_SLACK_M).to_string(),
            format!("{:.4}", r.path_length_m),
            format!("{:.4}", r.odom_path_length_m),
            format!("{:.3}", r.duration_s),
            r.frames.to_string(),
            r.replans.to_string(),
            r.contact.soft_events.to_string(),
            r.contact.hard_events.to_string(),
            format!("{:.3}", r.contact.soft_s),
            format!("{:.3}", r.contact.hard_s),
            r.contact.hard_by_robot.to_string(),
            r.contact.pedestrian_events.to_string(),
            r.contact.pedestrian_by_robot.to_string(),
            r.reason.clone(),
        ])?;
    }
    Ok(String::from_utf8(w.into_inner()?)?)
}

/// Wilson score interval of `k` successes in `n` trials at 95 % (z = 1.96),
/// as fractions (0, 0 when n = 0).
pub fn wilson_95(k: u32, n: u32) -> (f64, f64) {
    if n == 0 {
        return (0.0, 0.0);
    }
    let z = 1.96_f64;
    let (n, p) = (f64::from(n), f64::from(k) / f64::from(n));
    let denom = 1.0 + z * z / n;
    let centre = (p + z * z / (2.0 * n)) / denom;
    let half = z * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt() / denom;
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

/// Why a trial failed, in the robot's own words where it gave them: the
/// question it asked (its target named generically), the executor's
/// failure reason, or for a mission it believed done, `hard_contact` /
/// `outside_radius`. Numbers are dropped so like reasons group.
pub fn failure_reason(r: &TrialRecord) -> String {
    use crate::metrics::Outcome;
    let generic = |s: &str| -> String {
        let mut out = String::new();
        let lower = s.to_lowercase();
        if let Some(i) = lower.find("could not find the ") {
            let rest = &s[i + "could not find the ".len()..];
            let end = rest.find(['.', ',', '?']).unwrap_or(rest.len());
            out.push_str(&s[..i]);
            out.push_str("could not find the <target>");
            out.push_str(&rest[end..]);
        } else {
            out.push_str(s);
        }
        let no_digits: String = out.chars().map(|c| if c.is_ascii_digit() { '#' } else { c }).collect();
        let mut squeezed = String::new();
        for c in no_digits.chars() {
            if !(c == '#' && squeezed.ends_with('#')) {
                squeezed.push(c);
            }
        }
        squeezed.replace('|', "/")
    };
    match r.outcome {
        Outcome::Succeeded if r.completed() && r.contact.hard_by_robot > 0 => "hard_contact (completed)".into(),
        Outcome::Succeeded => "outside_radius (completed)".into(),
        other => format!("{}: {}", other.as_str(), generic(&r.reason)),
    }
}

struct FamilyRow {
    trials: u32,
    successes: u32,
    success_025: u32,
    soft: u32,
    robot_people: u32,
    robot_things: u32,
    walked_into: u32,
    stops: Vec<f64>,
    path_m: f64,
}

fn family_row(records: &[&TrialRecord]) -> FamilyRow {
    let count = |f: &dyn Fn(&TrialRecord) -> bool| records.iter().filter(|r| f(r)).count() as u32;
    FamilyRow {
        trials: records.len() as u32,
        successes: count(&|r| r.success()),
        success_025: count(&|r| r.success_within(crate::aggregate::TIGHT_SLACK_M)),
        soft: count(&|r| r.contact.soft_events > 0),
        robot_people: count(&|r| r.contact.pedestrian_by_robot > 0),
        robot_things: count(&|r| r.contact.hard_by_robot > r.contact.pedestrian_by_robot),
        walked_into: count(&|r| r.contact.hard_events > r.contact.hard_by_robot),
        stops: records.iter().filter(|r| r.completed()).map(|r| r.stop_error_m().abs()).collect(),
        path_m: if records.is_empty() {
            0.0
        } else {
            records.iter().map(|r| r.path_length_m).sum::<f64>() / records.len() as f64
        },
    }
}

fn family_line(out: &mut String, label: &str, mode: &str, row: &FamilyRow) {
    let (lo, hi) = wilson_95(row.successes, row.trials);
    let p = |k: u32| if row.trials == 0 { 0.0 } else { 100.0 * f64::from(k) / f64::from(row.trials) };
    let stop = if row.stops.is_empty() {
        "—".to_string()
    } else {
        let n = row.stops.len() as f64;
        let m = row.stops.iter().sum::<f64>() / n;
        let sd = (row.stops.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n).sqrt();
        format!("{m:.2} ± {sd:.2}")
    };
    let _ = writeln!(
        out,
        "| {label} | {mode} | {} | {} | {:.1} [{:.1}, {:.1}] | {:.1} | {:.1} | {} ({:.1}) | {} ({:.1}) | {} ({:.1}) | {} | {:.1} |",
        row.trials,
        row.successes,
        p(row.successes),
        100.0 * lo,
        100.0 * hi,
        p(row.success_025),
        p(row.soft),
        row.robot_people,
        p(row.robot_people),
        row.robot_things,
        p(row.robot_things),
        row.walked_into,
        p(row.walked_into),
        stop,
        row.path_m,
    );
}

/// The generated worlds' section: success with its 95 % Wilson interval per
/// family (all modes, then per mode) and overall, trials in which the robot
/// touched a person / a thing, trials in which a person walked into it,
/// the stopping error, and the failures grouped by the robot's own reason.
/// `family_of` maps a scenario name to its family; records of scenarios
/// without one are left out.
pub fn family_markdown(family_of: &std::collections::BTreeMap<String, String>, records: &[TrialRecord]) -> String {
    use std::collections::BTreeMap;
    let mut sorted: Vec<&TrialRecord> = records.iter().filter(|r| family_of.contains_key(&r.scenario)).collect();
    sorted.sort_by(|a, b| (&a.scenario, a.mode, a.trial).cmp(&(&b.scenario, b.mode, b.trial)));
    let mut by_family: BTreeMap<&str, Vec<&TrialRecord>> = BTreeMap::new();
    for r in &sorted {
        by_family.entry(family_of[&r.scenario].as_str()).or_default().push(r);
    }
    let worlds: std::collections::BTreeSet<&str> = sorted.iter().map(|r| r.scenario.as_str()).collect();
    let mut out = String::new();
    let _ = writeln!(out, "## Generated worlds — per family\n");
    let _ = writeln!(
        out,
        "{} trials in {} worlds. Success % with its 95 % Wilson interval in brackets. Contact columns: trials \
in which the robot moved into a person / into a thing (structure or an object), and in which a person walked \
into it (not a failure); count (%).\n",
        sorted.len(),
        worlds.len()
    );
    out.push_str("| Family | Mode | Trials | Successes | Success % [95 % CI] | Success % at 0.25 m | Soft % trials | Robot hit a person | Robot hit a thing | Walked into | Stopping error (m) | Path (m) |\n");
    out.push_str("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for (fam, rs) in &by_family {
        family_line(&mut out, fam, "all", &family_row(rs));
        for mode in Mode::ALL {
            let of: Vec<&TrialRecord> = rs.iter().copied().filter(|r| r.mode == mode).collect();
            if !of.is_empty() {
                family_line(&mut out, fam, mode.as_str(), &family_row(&of));
            }
        }
    }
    family_line(&mut out, "**overall**", "all", &family_row(&sorted));
    for mode in Mode::ALL {
        let of: Vec<&TrialRecord> = sorted.iter().copied().filter(|r| r.mode == mode).collect();
        if !of.is_empty() {
            family_line(&mut out, "**overall**", mode.as_str(), &family_row(&of));
        }
    }
    let mut reasons: BTreeMap<String, BTreeMap<&str, u32>> = BTreeMap::new();
    for r in sorted.iter().filter(|r| !r.success()) {
        *reasons.entry(failure_reason(r)).or_default().entry(family_of[&r.scenario].as_str()).or_insert(0) += 1;
    }
    let _ = writeln!(out, "\n### Failures by the robot's reason\n");
    let fams: Vec<&str> = by_family.keys().copied().collect();
    let _ = writeln!(out, "| Reason | {} | Total |", fams.join(" | "));
    let _ = writeln!(out, "|---|{}---:|", "---:|".repeat(fams.len()));
    let mut rows: Vec<(u32, String, String)> = reasons
        .iter()
        .map(|(why, per)| {
            let total: u32 = per.values().sum();
            let cells: Vec<String> = fams.iter().map(|f| per.get(f).copied().unwrap_or(0).to_string()).collect();
            (total, why.clone(), cells.join(" | "))
        })
        .collect();
    rows.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
    for (total, why, cells) in rows {
        let _ = writeln!(out, "| {why} | {cells} | {total} |");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aggregate::summarise;
    use crate::metrics::tests::record;
    use crate::metrics::{Outcome, Point2};

    fn refs() -> Vec<ScenarioRef> {
        vec![
            ScenarioRef {
                name: "indoor".into(),
                title: "Indoor office".into(),
                paper_table_v: Some("Indoor".into()),
                paper_table_iv: None,
            },
            ScenarioRef {
                name: "corridor".into(),
                title: "Featureless corridor".into(),
                paper_table_v: None,
                paper_table_iv: Some("Featureless Corridor".into()),
            },
        ]
    }

    fn records() -> Vec<TrialRecord> {
        let mut rs = vec![record(0, Outcome::Succeeded, (10.0, 0.0)), record(1, Outcome::Failed, (5.0, 0.0))];
        for (i, mode) in [Mode::Geometric, Mode::Hybrid].into_iter().enumerate() {
            let mut r = record(i as u32, Outcome::Succeeded, (10.0, 0.0));
            r.scenario = "corridor".into();
            r.mode = mode;
            rs.push(r);
        }
        rs
    }

    #[test]
    fn table_v_puts_the_papers_numbers_beside_ours() {
        let md = table_v_markdown(&refs(), &summarise(&records()), None);
        let row = md.lines().find(|l| l.starts_with("| Indoor office")).expect(&md);
        assert!(row.contains("| 2 |"), "{row}");
        assert!(row.contains("50.0 (100.0)"), "{row}");
        assert!(row.contains("(12.4)"), "{row}");
        assert!(row.contains("(0.03 ± 0.01)"), "{row}");
        // The slack is stated and the collision cells are shares of trials beside the paper's.
        assert!(row.contains("| 0.50 |"), "{row}");
        assert!(row.contains("0.0 (10.0)"), "{row}");
        // The corridor ran in hybrid mode too but stands for no Table V row: listed without paper figures.
        let corridor = md.lines().find(|l| l.starts_with("| Featureless corridor")).expect(&md);
        assert!(corridor.contains("100.0 (—)"), "{corridor}");
    }

    #[test]
    fn another_runs_figures_stand_in_brackets_beside_ours() {
        // The other run: every trial of the fixture a success (an upper bound).
        let upper: Vec<TrialRecord> = records()
            .into_iter()
            .map(|r| TrialRecord { outcome: Outcome::Succeeded, final_position: Point2::new(10.0, 0.0), ..r })
            .collect();
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("summary.csv"), summary_csv(&refs(), &summarise(&upper)).unwrap()).unwrap();
        std::fs::write(dir.path().join("report.md"), markdown(&refs(), &summarise(&upper), 7, 2, "oracle", None))
            .unwrap();
        let beside = Beside::load(dir.path()).unwrap();
        assert_eq!(beside.label, "oracle");
        let md = markdown(&refs(), &summarise(&records()), 7, 2, "realistic", Some(&beside));
        assert!(md.contains("ours [the same with perception `oracle`] (paper)"), "{md}");
        let row = md.lines().find(|l| l.starts_with("| Indoor office")).expect(&md);
        assert!(row.contains("50.0 [100.0] (100.0)"), "{row}");
        let iv = md.lines().find(|l| l.starts_with("| Featureless corridor (")).expect(&md);
        assert!(iv.contains("100.0 [100.0] (92.0)") && iv.contains("not run (15.0)"), "{iv}");
        // A directory without a summary is named in the error.
        let empty = tempfile::tempdir().unwrap();
        let e = format!("{:#}", Beside::load(empty.path()).unwrap_err());
        assert!(e.contains("--beside") && e.contains("summary.csv"), "{e}");
    }

    #[test]
    fn table_iv_marks_modes_not_run() {
        let md = table_iv_markdown(&refs(), &summarise(&records()), None);
        let row = md.lines().find(|l| l.starts_with("| Featureless corridor")).expect(&md);
        assert!(row.contains("100.0 (92.0)"), "{row}");
        assert!(row.contains("not run (15.0)"), "{row}");
        assert!(row.contains("100.0 (95.0)"), "{row}");
        assert!(!md.contains("Indoor office"), "scenarios without a Table IV row stay out");
    }

    #[test]
    fn the_csv_has_one_row_per_scenario_and_mode_with_paper_columns() {
        let csv = summary_csv(&refs(), &summarise(&records())).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 4, "{csv}");
        assert!(lines[0].starts_with("scenario,title,mode"));
        assert!(lines[1].starts_with("indoor,Indoor office,hybrid,2,1,50.00,0.50,"), "{}", lines[1]);
        assert!(lines[1].ends_with("Indoor,100,10,0,12.4,0.03"), "{}", lines[1]);
        assert!(lines[2].starts_with("corridor,Featureless corridor,geometric"), "{}", lines[2]);
        assert!(lines[2].ends_with("Featureless Corridor,92,,,,"), "{}", lines[2]);
    }

    #[test]
    fn the_same_records_render_the_same_bytes() {
        let rs = records();
        let mut rev = rs.clone();
        rev.reverse();
        let a = markdown(&refs(), &summarise(&rs), 7, 2, "realistic", None);
        let b = markdown(&refs(), &summarise(&rev), 7, 2, "realistic", None);
        assert!(a.contains("Perception `realistic`"));
        assert_eq!(a, b);
        assert_eq!(trials_csv(&rs).unwrap(), trials_csv(&rev).unwrap());
    }

    #[test]
    fn the_trial_csv_recomputes_success_and_the_stopping_error() {
        let csv = trials_csv(&records()).unwrap();
        let failed = csv.lines().find(|l| l.starts_with("indoor,hybrid,1,")).unwrap();
        // ‖(10,0) − (5,0)‖ = 5, asked 0.5 → 4.5 too far.
        assert!(failed.contains(",failed,false,"), "{failed}");
        assert!(failed.contains(",5.0000,4.5000,false,"), "{failed}");
    }

    #[test]
    fn wilson_intervals_match_the_textbook() {
        // 8 of 10: [0.490, 0.943] (Wilson 1927; e.g. Agresti & Coull 1998).
        let (lo, hi) = wilson_95(8, 10);
        assert!((lo - 0.4902).abs() < 1e-3 && (hi - 0.9433).abs() < 1e-3, "{lo} {hi}");
        let (lo, hi) = wilson_95(0, 20);
        assert!(lo == 0.0 && (hi - 0.1611).abs() < 1e-3, "{hi}");
        assert_eq!(wilson_95(0, 0), (0.0, 0.0));
        let (lo, hi) = wilson_95(50, 50);
        assert!((lo - 0.9287).abs() < 1e-3 && hi == 1.0, "{lo}");
    }

    #[test]
    fn the_family_section_groups_by_family_and_reason() {
        let mut a = record(0, Outcome::Succeeded, (12.5, 2.0));
        a.scenario = "hall-1".into();
        let mut b = record(1, Outcome::Clarification, (1.0, 1.0));
        b.scenario = "hall-2".into();
        b.reason =
            "the robot asked: I could not find the potted plant. Where should I look, or should I skip it?".into();
        let mut c = record(2, Outcome::Clarification, (1.0, 1.0));
        c.scenario = "home-1".into();
        c.reason = "the robot asked: I could not find the chair. Where should I look, or should I skip it?".into();
        let mut d = record(3, Outcome::Succeeded, (12.5, 2.0));
        d.scenario = "indoor".into();
        let fam: std::collections::BTreeMap<String, String> =
            [("hall-1", "hall"), ("hall-2", "hall"), ("home-1", "home")].map(|(a, b)| (a.into(), b.into())).into();
        let md = family_markdown(&fam, &[c.clone(), a.clone(), b.clone(), d.clone()]);
        assert!(md.contains("3 trials in 3 worlds"), "{md}");
        assert!(md.contains("| hall | all | 2 |"), "{md}");
        assert!(
            md.contains("| could not find the <target>") || md.contains("could not find the <target>. Where"),
            "{md}"
        );
        assert!(md.contains("| clarification: the robot asked: I could not find the <target>. Where should I look, or should I skip it? | 1 | 1 | 2 |"), "{md}");
        // Order-independent.
        assert_eq!(md, family_markdown(&fam, &[d, b, a, c]));
    }
}
