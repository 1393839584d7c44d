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
    /// Success with the instructions' radii (slack below), %.
    pub success_pct: f64,
    /// The slacks of the success radii beyond the asked distance, metres
    /// (distinct values, ascending).
    pub slack_m: Vec<f64>,
    /// Success with |stopping error| ≤ 0.25 m, %.
    pub success_025_pct: f64,
    /// Share of trials with at least one soft / hard collision, % (primary).
    /// Hard: contact the robot made (what fails a trial).
    pub soft_trials_pct: f64,
    pub hard_trials_pct: f64,
    /// Share of trials in which a person walked into the stopped robot, %.
    #[serde(default)]
    pub walked_into_trials_pct: f64,
    /// Share of trials with any contact with a pedestrian, whoever made it, %.
    #[serde(default)]
    pub pedestrian_trials_pct: f64,
    /// Mean share of mission time inside a no-go region / touching something, % (secondary).
    pub soft_time_pct: f64,
    pub hard_time_pct: f64,
    /// Mean true path length, metres.
    pub path_m: f64,
    /// Trials that completed every step (the stopping error is over these).
    pub completed: u32,
    /// Mean |stopping error| and its population standard deviation, metres.
    pub stop_abs_m: f64,
    pub stop_abs_std_m: f64,
    /// Mean signed stopping error (positive: farther than asked), metres.
    pub stop_bias_m: f64,
    /// Mean ‖G_d − R_d‖ over all trials, metres.
    pub final_error_m: f64,
    /// Mean mission time, sensor seconds.
    pub mission_s: f64,
    /// Simulated frames over all trials.
    pub frames: u64,
    /// Why the unsuccessful trials failed (cause → count): the outcome
    /// (`failed`, `timed_out`, `clarification`, `error`), or for a mission
    /// that completed, `hard_contact` or `outside_radius`.
    pub failures: BTreeMap<String, u32>,
}

/// The slack of "success at 0.25 m".
pub const TIGHT_SLACK_M: f64 = 0.25;

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
    let count = |f: &dyn Fn(&TrialRecord) -> bool| records.iter().filter(|r| f(r)).count() as u32;
    let successes = count(&|r| r.success());
    let completed: Vec<&&TrialRecord> = records.iter().filter(|r| r.completed()).collect();
    let stops: Vec<f64> = completed.iter().map(|r| r.stop_error_m().abs()).collect();
    let mut failures = BTreeMap::new();
    for r in records.iter().filter(|r| !r.success()) {
        let key = match r.outcome {
            Outcome::Succeeded if r.completed() && r.contact.hard_by_robot > 0 => "hard_contact",
            Outcome::Succeeded => "outside_radius",
            other => other.as_str(),
        };
        *failures.entry(key.to_string()).or_insert(0) += 1;
    }
    let mut slack_m: Vec<f64> = records.iter().map(|r| (r.slack_m() * 100.0).round() / 100.0).collect();
    slack_m.sort_by(f64::total_cmp);
    slack_m.dedup();
    Summary {
        scenario: scenario.to_string(),
        mode,
        trials,
        successes,
        success_pct: pct(successes, trials),
        slack_m,
        success_025_pct: pct(count(&|r| r.success_within(TIGHT_SLACK_M)), trials),
        soft_trials_pct: pct(count(&|r| r.contact.soft_events > 0), trials),
        hard_trials_pct: pct(count(&|r| r.contact.hard_by_robot > 0), trials),
        walked_into_trials_pct: pct(count(&|r| r.contact.hard_events > r.contact.hard_by_robot), trials),
        pedestrian_trials_pct: pct(count(&|r| r.contact.pedestrian_events > 0), trials),
        soft_time_pct: 100.0 * mean(records.iter().map(|r| r.soft_time_share())),
        hard_time_pct: 100.0 * mean(records.iter().map(|r| r.hard_time_share())),
        path_m: mean(records.iter().map(|r| r.path_length_m)),
        completed: completed.len() as u32,
        stop_abs_m: mean(stops.iter().copied()),
        stop_abs_std_m: population_std(&stops),
        stop_bias_m: mean(completed.iter().map(|r| r.stop_error_m())),
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
        rs[2].contact.hard_by_robot = 2;
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
        // Trial 0 succeeds; trial 1 ends 2 m off (radius 1 m); 2 failed; 3 timed out.
        assert_eq!(hybrid.successes, 1);
        assert_eq!(hybrid.success_pct, 25.0);
        assert_eq!(hybrid.slack_m, vec![0.5]);
        // Trial 0 stopped on G_d, 0.5 m closer than asked: not within 0.25 m.
        assert_eq!(hybrid.success_025_pct, 0.0);
        // Stopping error over the two completed trials: |0 − 0.5| and |2 − 0.5|.
        assert_eq!(hybrid.completed, 2);
        assert!((hybrid.stop_abs_m - 1.0).abs() < 1e-12);
        assert!((hybrid.stop_abs_std_m - 0.5).abs() < 1e-12);
        assert!((hybrid.stop_bias_m - 0.5).abs() < 1e-12);
        // Time shares 10 %, 0, 0, 0 → 2.5 %; 0, 0, 5 %, 0 → 1.25 %.
        assert!((hybrid.soft_time_pct - 2.5).abs() < 1e-12);
        assert!((hybrid.hard_time_pct - 1.25).abs() < 1e-12);
        assert_eq!(hybrid.soft_trials_pct, 25.0);
        assert_eq!(hybrid.hard_trials_pct, 25.0);
        assert!((hybrid.path_m - 13.0).abs() < 1e-12);
        assert_eq!(hybrid.frames, 800);
        assert_eq!(hybrid.failures.get("outside_radius"), Some(&1));
        assert_eq!(hybrid.failures.get("failed"), Some(&1));
        assert_eq!(hybrid.failures.get("timed_out"), Some(&1));
    }

    #[test]
    fn a_completed_trial_with_hard_contact_fails_as_such() {
        let mut r = record(0, Outcome::Succeeded, (10.0, 0.5));
        r.contact.hard_events = 1;
        r.contact.hard_by_robot = 1;
        let s = summarise(&[r]);
        assert_eq!(s[0].successes, 0);
        assert_eq!(s[0].failures.get("hard_contact"), Some(&1));
        assert_eq!(s[0].hard_trials_pct, 100.0);
        assert_eq!(s[0].completed, 1, "its stopping error still counts");
    }

    #[test]
    fn a_person_walking_into_the_stopped_robot_is_counted_apart() {
        let mut walked_into = record(0, Outcome::Succeeded, (10.0, 0.5));
        walked_into.contact.hard_events = 1;
        walked_into.contact.pedestrian_events = 1;
        let mut ran_into = record(1, Outcome::Succeeded, (10.0, 0.5));
        ran_into.contact.hard_events = 2;
        ran_into.contact.hard_by_robot = 1;
        ran_into.contact.pedestrian_events = 1;
        ran_into.contact.pedestrian_by_robot = 1;
        let s = summarise(&[walked_into, ran_into]);
        assert_eq!(s[0].successes, 1, "only the trial whose robot made contact fails");
        assert_eq!(s[0].hard_trials_pct, 50.0);
        assert_eq!(s[0].walked_into_trials_pct, 100.0, "both were walked into once");
        assert_eq!(s[0].pedestrian_trials_pct, 100.0);
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
