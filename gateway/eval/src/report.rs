//! Markdown and CSV tables, each beside the paper's numbers.
//!
//! Nothing here reads a clock: the same summaries render to the same bytes,
//! which is what the determinism check compares.

use std::fmt::Write as _;

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

/// Table V analogue: one row per scenario run in hybrid mode, every cell
/// "ours (paper)".
pub fn table_v_markdown(scenarios: &[ScenarioRef], summaries: &[Summary]) -> String {
    let mut out = String::new();
    out.push_str(
        "| Environment (paper row) | Trials | Success % | Soft collision % | Hard collision % | Avg. path (m) | Drift error (m) | Mission time (s) | Trials with soft / hard collision % |\n",
    );
    out.push_str("|---|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for sc in scenarios {
        let Some(s) = find(summaries, &sc.name, Mode::Hybrid) else { continue };
        let p = sc.paper_table_v.as_deref().and_then(paper::table_v);
        let row_name = match p {
            Some(p) => format!("{} ({})", sc.title, p.environment),
            None => sc.title.clone(),
        };
        let drift = match p {
            Some(p) => format!("{:.2} ± {:.2} ({:.2} ± {:.2})", s.drift_m, s.drift_std_m, p.drift_m, p.drift_std_m),
            None => format!("{:.2} ± {:.2} (—)", s.drift_m, s.drift_std_m),
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {} | {} | {:.1} | {:.0} / {:.0} |",
            row_name,
            s.trials,
            pair(s.success_pct, p.map(|p| p.success_pct), 1),
            pair(s.soft_collision_pct, p.map(|p| p.soft_collision_pct), 1),
            pair(s.hard_collision_pct, p.map(|p| p.hard_collision_pct), 1),
            pair(s.path_m, p.map(|p| p.path_m), 1),
            drift,
            s.mission_s,
            s.soft_trials_pct,
            s.hard_trials_pct,
        );
    }
    out
}

/// Table IV analogue: success % per mode, "ours (paper)".
pub fn table_iv_markdown(scenarios: &[ScenarioRef], summaries: &[Summary]) -> String {
    let mut out = String::new();
    out.push_str("| Scenario (paper row) | Constraint | Geometric % | Visual % | Hybrid % |\n");
    out.push_str("|---|---|---:|---:|---:|\n");
    for sc in scenarios {
        let Some(key) = sc.paper_table_iv.as_deref() else { continue };
        let p = paper::table_iv(key);
        let cell = |mode: Mode| match find(summaries, &sc.name, mode) {
            Some(s) => pair(s.success_pct, p.map(|p| p.success_pct(mode)), 1),
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

/// Every (scenario, mode) with every figure, ours only.
pub fn full_markdown(scenarios: &[ScenarioRef], summaries: &[Summary]) -> String {
    let mut out = String::new();
    out.push_str("| Scenario | Mode | Trials | Success % | Soft % time | Hard % time | Soft % trials | Hard % trials | Path (m) | Drift (m) | Final error (m) | Time (s) | Frames | Failures |\n");
    out.push_str("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n");
    for sc in scenarios {
        for mode in Mode::ALL {
            let Some(s) = find(summaries, &sc.name, mode) else { continue };
            let failures: Vec<String> = s.failures.iter().map(|(k, v)| format!("{k} {v}")).collect();
            let _ = writeln!(
                out,
                "| {} | {} | {} | {:.1} | {:.1} | {:.1} | {:.0} | {:.0} | {:.1} | {:.2} ± {:.2} | {:.2} | {:.1} | {} | {} |",
                sc.title,
                mode,
                s.trials,
                s.success_pct,
                s.soft_collision_pct,
                s.hard_collision_pct,
                s.soft_trials_pct,
                s.hard_trials_pct,
                s.path_m,
                s.drift_m,
                s.drift_std_m,
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
pub fn markdown(scenarios: &[ScenarioRef], summaries: &[Summary], master_seed: u64, trials: u32) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# vlnav evaluation\n");
    let _ = writeln!(
        out,
        "Master seed {master_seed}, {trials} trials per scenario and mode. Cells read \"ours (paper)\".\n"
    );
    let v = table_v_markdown(scenarios, summaries);
    if v.lines().count() > 2 {
        let _ = writeln!(
            out,
            "## Table V — success, collisions, path and drift per environment (hybrid instructions)\n\n{v}"
        );
    }
    let iv = table_iv_markdown(scenarios, summaries);
    if iv.lines().count() > 2 {
        let _ = writeln!(out, "## Table IV — success % per navigation modality\n\n{iv}");
    }
    let _ = writeln!(out, "## Every scenario and mode\n\n{}", full_markdown(scenarios, summaries));
    out.push_str(
        "Success: the mission ended SUCCEEDED with every step done and the true final position within d_s of the true \
destination. Soft / hard collision %: mean share of mission time inside a no-go region / touching structure \
(the paper's figures are rates, not shares of trials); \"% trials\" counts trials with at least one such event. \
Drift: mean of max(0, ‖G_d − R_d‖ − d_s) ± population standard deviation. Time: sensor seconds.\n",
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
        "soft_collision_pct",
        "hard_collision_pct",
        "soft_trials_pct",
        "hard_trials_pct",
        "path_m",
        "drift_m",
        "drift_std_m",
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
                format!("{:.3}", s.soft_collision_pct),
                format!("{:.3}", s.hard_collision_pct),
                format!("{:.2}", s.soft_trials_pct),
                format!("{:.2}", s.hard_trials_pct),
                format!("{:.3}", s.path_m),
                format!("{:.4}", s.drift_m),
                format!("{:.4}", s.drift_std_m),
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
        "final_x",
        "final_y",
        "final_error_m",
        "drift_m",
        "path_length_m",
        "odom_path_length_m",
        "duration_s",
        "frames",
        "replans",
        "soft_events",
        "hard_events",
        "soft_s",
        "hard_s",
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
            format!("{:.4}", r.final_position.x),
            format!("{:.4}", r.final_position.y),
            format!("{:.4}", r.final_error_m()),
            format!("{:.4}", r.drift_m()),
            format!("{:.4}", r.path_length_m),
            format!("{:.4}", r.odom_path_length_m),
            format!("{:.3}", r.duration_s),
            r.frames.to_string(),
            r.replans.to_string(),
            r.contact.soft_events.to_string(),
            r.contact.hard_events.to_string(),
            format!("{:.3}", r.contact.soft_s),
            format!("{:.3}", r.contact.hard_s),
            r.reason.clone(),
        ])?;
    }
    Ok(String::from_utf8(w.into_inner()?)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aggregate::summarise;
    use crate::metrics::Outcome;
    use crate::metrics::tests::record;

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
        let md = table_v_markdown(&refs(), &summarise(&records()));
        let row = md.lines().find(|l| l.starts_with("| Indoor office")).expect(&md);
        assert!(row.contains("| 2 |"), "{row}");
        assert!(row.contains("50.0 (100.0)"), "{row}");
        assert!(row.contains("(12.4)"), "{row}");
        assert!(row.contains("(0.03 ± 0.01)"), "{row}");
        // The corridor ran in hybrid mode too but stands for no Table V row: listed without paper figures.
        let corridor = md.lines().find(|l| l.starts_with("| Featureless corridor")).expect(&md);
        assert!(corridor.contains("100.0 (—)"), "{corridor}");
    }

    #[test]
    fn table_iv_marks_modes_not_run() {
        let md = table_iv_markdown(&refs(), &summarise(&records()));
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
        assert!(lines[1].starts_with("indoor,Indoor office,hybrid,2,1,50.00"), "{}", lines[1]);
        assert!(lines[1].ends_with("Indoor,100,10,0,12.4,0.03"), "{}", lines[1]);
        assert!(lines[2].starts_with("corridor,Featureless corridor,geometric"), "{}", lines[2]);
        assert!(lines[2].ends_with("Featureless Corridor,92,,,,"), "{}", lines[2]);
    }

    #[test]
    fn the_same_records_render_the_same_bytes() {
        let rs = records();
        let mut rev = rs.clone();
        rev.reverse();
        let a = markdown(&refs(), &summarise(&rs), 7, 2);
        let b = markdown(&refs(), &summarise(&rev), 7, 2);
        assert_eq!(a, b);
        assert_eq!(trials_csv(&rs).unwrap(), trials_csv(&rev).unwrap());
    }

    #[test]
    fn the_trial_csv_recomputes_success_and_drift() {
        let csv = trials_csv(&records()).unwrap();
        let failed = csv.lines().find(|l| l.starts_with("indoor,hybrid,1,")).unwrap();
        // ‖(10,0) − (5,0)‖ = 5, d_s = 1 → drift 4.
        assert!(failed.contains(",failed,false,"), "{failed}");
        assert!(failed.contains(",5.0000,4.0000,"), "{failed}");
    }
}
