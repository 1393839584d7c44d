//! How fast a robot is stopped after a fault, read from the edge agent's
//! [`StepRecord`]s, in the robot's sensor time.
//!
//! A record at stamp `s` says what the governor applied from `s` for one
//! frame period, and which command it held (`command`: the stamp of the
//! frame that command answers, and its twist).
//!
//! - A record is *commanded zero* when the governor is not following a fresh
//!   command (deadman tripped, no command, e-stop: it applies zero at once),
//!   or the fresh command it follows asks for zero twist (it ramps down at the
//!   acceleration limits).
//! - A *motion command* is a command with a non-zero twist.
//! - After a fault at sensor time `t_f`, the robot is *commanded zero* at `z`,
//!   the stamp of the first record at or after `t_f` that is commanded zero.
//!   `c` is the stamp of the newest motion command held by any record before
//!   `z`: the last frame that got a fresh command to move.
//! - **Bound**: `z − c ≤ deadman_timeout + frame period`. The deadman lets a
//!   command stamped `c` drive records stamped up to `c + deadman_timeout`;
//!   the next record, at most one period later, must apply zero.
//! - The applied twist reaches zero at `a ≥ z` (the first record from `z` on
//!   whose applied twist is zero): at once when the deadman trips, after the
//!   ramp-down when the gateway commanded zero. `a − z` is at most the time
//!   the acceleration limits need to brake from the twist applied before `z`,
//!   rounded up to whole frames.
//!
//! Independently of any fault, no record may apply motion on a command older
//! than the deadman timeout ([`stale_motion`]).

use vlnav_edge_agent::{StepRecord, Twist, Verdict};

/// Slack for float sums of frame periods.
pub const EPS: f64 = 1e-6;

/// The robot's acceleration limits (the simulated Husky's, `vlnav_sim::HuskyParams`).
#[derive(Clone, Copy, Debug)]
pub struct Braking {
    pub linear_accel: f64,
    pub angular_accel: f64,
}

impl Default for Braking {
    fn default() -> Self {
        let p = vlnav_sim::HuskyParams::default();
        Braking { linear_accel: p.max_linear_accel, angular_accel: p.max_angular_accel }
    }
}

fn is_zero(t: &Twist) -> bool {
    t.linear.abs() < 1e-9 && t.angular.abs() < 1e-9
}

/// Whether the record's governor was told (or decided) to hold zero.
pub fn commanded_zero(r: &StepRecord) -> bool {
    match r.verdict {
        Verdict::Commanded { .. } => r.command.is_none_or(|(_, t)| is_zero(&t)),
        _ => true,
    }
}

/// Whether the robot moved during this record's period.
pub fn moving(r: &StepRecord) -> bool {
    !is_zero(&r.applied)
}

/// Records that applied motion while the command they held was older than
/// `deadman_s` (or while they held none): each is a deadman violation.
pub fn stale_motion(records: &[StepRecord], deadman_s: f64) -> Vec<&StepRecord> {
    records.iter().filter(|r| moving(r) && r.command.is_none_or(|(c, _)| r.stamp - c > deadman_s + EPS)).collect()
}

/// The stop that followed a fault (see the module's definitions).
#[derive(Clone, Debug, PartialEq)]
pub struct Stop {
    /// `t_f`.
    pub fault: f64,
    /// `c`: the last frame with a fresh command to move.
    pub last_motion_command: f64,
    /// `z`.
    pub commanded_zero: f64,
    /// `a`.
    pub applied_zero: Option<f64>,
    /// The twist applied just before `z`.
    pub speed_before: Twist,
}

impl Stop {
    /// `z − c`, the quantity the deadman bounds.
    pub fn latency(&self) -> f64 {
        self.commanded_zero - self.last_motion_command
    }

    /// `a − c`: until the wheels were told zero.
    pub fn applied_latency(&self) -> Option<f64> {
        self.applied_zero.map(|a| a - self.last_motion_command)
    }

    /// Whether `z − c ≤ deadman + period`.
    pub fn within_deadman(&self, deadman_s: f64, period_s: f64) -> bool {
        self.latency() <= deadman_s + period_s + EPS
    }

    /// Whether the ramp from `z` to `a` took no longer than braking from
    /// `speed_before` at the acceleration limits, in whole frames.
    pub fn ramp_within(&self, braking: Braking, period_s: f64) -> bool {
        let Some(a) = self.applied_zero else { return false };
        let need = (self.speed_before.linear.abs() / braking.linear_accel)
            .max(self.speed_before.angular.abs() / braking.angular_accel);
        let frames = (need / period_s - EPS).ceil().max(0.0);
        a - self.commanded_zero <= frames * period_s + EPS
    }
}

/// Finds the stop after a fault at sensor time `fault` (`None` when no
/// record from `fault` on is commanded zero, or no motion command came before).
pub fn stop_after(records: &[StepRecord], fault: f64) -> Option<Stop> {
    let zi = records.iter().position(|r| r.stamp >= fault - EPS && commanded_zero(r))?;
    let z = &records[zi];
    let last_motion_command = records[..zi]
        .iter()
        .filter_map(|r| r.command.filter(|(_, t)| !is_zero(t)).map(|(s, _)| s))
        .fold(None, |m: Option<f64>, s| Some(m.map_or(s, |m| m.max(s))))?;
    let applied_zero = records[zi..].iter().find(|r| !moving(r)).map(|r| r.stamp);
    let speed_before = if zi > 0 { records[zi - 1].applied } else { Twist::ZERO };
    Some(Stop { fault, last_motion_command, commanded_zero: z.stamp, applied_zero, speed_before })
}

/// Records in `[from, to)` that applied motion: a robot that should have been
/// held still moved.
pub fn moved_between(records: &[StepRecord], from: f64, to: f64) -> Vec<&StepRecord> {
    records.iter().filter(|r| r.stamp >= from - EPS && r.stamp < to - EPS && moving(r)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(stamp: f64, command: Option<(f64, f64)>, applied: f64, verdict: Verdict) -> StepRecord {
        StepRecord {
            seq: 0,
            stamp,
            odom: Default::default(),
            truth: None,
            command: command.map(|(s, v)| (s, Twist::new(v, 0.0))),
            applied: Twist::new(applied, 0.0),
            verdict,
            idle: false,
            mission_id: "m".into(),
        }
    }

    const GO: Verdict = Verdict::Commanded { clamped: false };

    #[test]
    fn a_deadman_stop_is_measured_from_the_last_motion_command() {
        // Commands stop after frame 1.0; the deadman (0.3 s) trips at 1.4.
        let rs = vec![
            rec(1.0, Some((1.0, 0.5)), 0.5, GO),
            rec(1.1, Some((1.0, 0.5)), 0.5, GO),
            rec(1.2, Some((1.0, 0.5)), 0.5, GO),
            rec(1.3, Some((1.0, 0.5)), 0.5, GO),
            rec(1.4, Some((1.0, 0.5)), 0.0, Verdict::DeadmanTripped),
        ];
        let s = stop_after(&rs, 1.05).unwrap();
        assert!((s.latency() - 0.4).abs() < 1e-9);
        assert!(s.within_deadman(0.3, 0.1));
        assert!(!s.within_deadman(0.2, 0.1));
        assert_eq!(s.applied_zero, Some(1.4));
        assert!(s.ramp_within(Braking { linear_accel: 3.0, angular_accel: 6.0 }, 0.1));
        assert!(stale_motion(&rs, 0.3).is_empty());
        assert_eq!(stale_motion(&rs, 0.25).len(), 1);
    }

    #[test]
    fn a_zero_command_is_a_stop_and_the_ramp_is_bounded_by_braking() {
        let rs = vec![
            rec(1.0, Some((1.0, 0.9)), 0.9, GO),
            rec(1.1, Some((1.1, 0.0)), 0.6, GO),
            rec(1.2, Some((1.2, 0.0)), 0.3, GO),
            rec(1.3, Some((1.3, 0.0)), 0.0, GO),
        ];
        let s = stop_after(&rs, 1.0).unwrap();
        assert!((s.latency() - 0.1).abs() < 1e-9);
        assert_eq!(s.applied_zero, Some(1.3));
        let b = Braking { linear_accel: 3.0, angular_accel: 6.0 };
        assert!(s.ramp_within(b, 0.1));
        assert!(!s.ramp_within(Braking { linear_accel: 9.0, angular_accel: 6.0 }, 0.1));
        assert!(moved_between(&rs, 1.3, 2.0).is_empty());
        assert_eq!(moved_between(&rs, 1.0, 1.3).len(), 3);
    }
}
