//! Aggregation of trial records into one summary per (scenario, mode).
//!
//! Records are sorted by (scenario, mode, trial) before any sum is taken, so
//! the summaries do not depend on the order in which concurrent trials
//! finished: the same records give bit-identical figures.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::metrics::{Mode, Outcome, TrialRecord};

/// The figures of one scenario run in one mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub scenario: String,
    pub mode: Mode,
    pub trials: u32,
    pub successes: u32,
    pub success_pct: f64,
    /// Mean share of mission time inside a no-go region, % (the paper's reading).
    pub soft_collision_pct: f64,
    /// Mean share of mission time touching structure, %.
    pub hard_collision_pct: f64,
    /// Share of trials with at least one soft / hard collision, %.
    pub soft_trials_pct: f64,
    pub hard_trials_pct: f64,
    /// Mean true path length, metres.
    pub path_m: f64,
    /// The paper's Ē_drift and its population standard deviation, metres.
    pub drift_m: f64,
    pub drift_std_m: f64,
    /// Mean ‖G_d − R_d‖, metres.
    pub final_error_m: f64,
    /// Mean mission time, sensor seconds.
    pub mission_s: f64,
    /// Simulated frames over all trials.
    pub frames: u64,
    /// How the unsuccessful trials ended (outcome → count), including
    /// `succeeded` for missions that finished outside the success radius.
    pub failures: BTreeMap<String, u32>,
}

fn mean(xs: impl Iterator<Item = f64> + Clone) -> f64 {
    let n = xs.clone().count();
    if n == 0 { 0.0 } else { xs.sum::<f64>() / n as f64 }
}

fn population_std(xs: &[f64]) -> f64 {
    if xs.is_empty() {
        return 0.0;
    }
    let m = xs.iter().sum::<f64>() / xs.len() as f64;
    (xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / xs.len() as f64).sqrt()
}

fn pct(part: u32, whole: u32) -> f64 {
    if whole == 0 { 0.0 } else { 100.0 * f64::from(part) / f64::from(whole) }
}

/// Summarises the trials of one (scenario, mode) group. `records` must all
/// belong to that group and be sorted by trial.
fn summarise_group(scenario: &str, mode: Mode, records: &[&TrialRecord]) -> Summary {
    let trials = records.len() as u32;
    let successes = records.iter().filter(|r| r.success()).count() as u32;
    let drifts: Vec<f64> = records.iter().map(|r| r.drift_m()).collect();
    let mut failures = BTreeMap::new();
    for r in records.iter().filter(|r| !r.success()) {
        let key = if r.outcome == Outcome::Succeeded { "outside_radius" } else { r.outcome.as_str() };
        *failures.entry(key.to_string()).or_insert(0) += 1;
    }
    Summary {
        scenario: scenario.to_string(),
        mode,
        trials,
        successes,
        success_pct: pct(successes, trials),
        soft_collision_pct: 100.0 * mean(records.iter().map(|r| r.soft_time_share())),
        hard_collision_pct: 100.0 * mean(records.iter().map(|r| r.hard_time_share())),
        soft_trials_pct: pct(records.iter().filter(|r| r.contact.soft_events > 0).count() as u32, trials),
        hard_trials_pct: pct(records.iter().filter(|r| r.contact.hard_events > 0).count() as u32, trials),
        path_m: mean(records.iter().map(|r| r.path_length_m)),
        drift_m: mean(drifts.iter().copied()),
        drift_std_m: population_std(&drifts),
        final_error_m: mean(records.iter().map(|r| r.final_error_m())),
        mission_s: mean(records.iter().map(|r| r.duration_s)),
        frames: records.iter().map(|r| u64::from(r.frames)).sum(),
        failures,
    }
}

/// One summary per (scenario, mode) present in `records`, ordered by
/// scenario name then mode.
pub fn summarise(records: &[TrialRecord]) -> Vec<Summary> {
    let mut groups: BTreeMap<(&str, Mode), Vec<&TrialRecord>> = BTreeMap::new();
    for r in records {
        groups.entry((r.scenario.as_str(), r.mode)).or_default().push(r);
    }
    groups
        .into_iter()
        .map(|((scenario, mode), mut rs)| {
            rs.sort_by_key(|r| r.trial);
            summarise_group(scenario, mode, &rs)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::tests::record;

    fn fixture() -> Vec<TrialRecord> {
        let mut rs = vec![
            record(0, Outcome::Succeeded, (10.0, 0.0)), // success, drift 0
            record(1, Outcome::Succeeded, (10.0, 2.0)), // outside radius, drift 1
            record(2, Outcome::Failed, (7.0, 0.0)),     // failed, drift 2
            record(3, Outcome::TimedOut, (10.5, 0.0)),  // timed out near, drift 0
        ];
        rs[0].contact.soft_events = 1;
        rs[0].contact.soft_s = 4.0; // 10 % of 40 s
        rs[2].contact.hard_events = 2;
        rs[2].contact.hard_s = 2.0; // 5 %
        rs[3].path_length_m = 16.0;
        let mut other = record(0, Outcome::Succeeded, (10.0, 0.0));
        other.mode = Mode::Visual;
        rs.push(other);
        rs
    }

    #[test]
    fn figures_follow_the_definitions() {
        let s = summarise(&fixture());
        assert_eq!(s.len(), 2);
        let hybrid = s.iter().find(|s| s.mode == Mode::Hybrid).unwrap();
        assert_eq!(hybrid.trials, 4);
        assert_eq!(hybrid.successes, 1);
        assert_eq!(hybrid.success_pct, 25.0);
        // Drift terms 0, 1, 2, 0 → mean 0.75, population std sqrt(0.6875).
        assert!((hybrid.drift_m - 0.75).abs() < 1e-12);
        assert!((hybrid.drift_std_m - 0.6875f64.sqrt()).abs() < 1e-12);
        // Time shares 10 %, 0, 0, 0 → 2.5 %; 0, 0, 5 %, 0 → 1.25 %.
        assert!((hybrid.soft_collision_pct - 2.5).abs() < 1e-12);
        assert!((hybrid.hard_collision_pct - 1.25).abs() < 1e-12);
        assert_eq!(hybrid.soft_trials_pct, 25.0);
        assert_eq!(hybrid.hard_trials_pct, 25.0);
        assert!((hybrid.path_m - 13.0).abs() < 1e-12);
        assert_eq!(hybrid.frames, 800);
        assert_eq!(hybrid.failures.get("outside_radius"), Some(&1));
        assert_eq!(hybrid.failures.get("failed"), Some(&1));
        assert_eq!(hybrid.failures.get("timed_out"), Some(&1));
    }

    #[test]
    fn the_order_trials_finished_in_does_not_change_a_figure() {
        let rs = fixture();
        let mut shuffled = rs.clone();
        shuffled.reverse();
        shuffled.swap(0, 2);
        assert_eq!(summarise(&rs), summarise(&shuffled));
    }

    #[test]
    fn groups_are_ordered_by_scenario_then_mode() {
        let mut rs = fixture();
        let mut g = record(0, Outcome::Succeeded, (10.0, 0.0));
        g.scenario = "garage".into();
        g.mode = Mode::Geometric;
        rs.push(g);
        let keys: Vec<(String, Mode)> = summarise(&rs).into_iter().map(|s| (s.scenario, s.mode)).collect();
        assert_eq!(
            keys,
            vec![("garage".into(), Mode::Geometric), ("indoor".into(), Mode::Visual), ("indoor".into(), Mode::Hybrid)]
        );
    }

    #[test]
    fn no_records_no_summaries() {
        assert!(summarise(&[]).is_empty());
    }
}
