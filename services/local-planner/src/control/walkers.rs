//! People: the detector's person boxes give where each person stands
//! (`cloud.rs`); `people::Tracker` links those places over frames and
//! tells walkers (faster than `PeopleParams::walking_mps` within the last
//! `keep_s`). No command — a turn in place, a way out of the sweep disc, a
//! path's (v, ω) — may bring the footprint within a walker's reach (their
//! radius plus how far they may have strayed), both carried on for
//! `PeopleParams::horizon_s`, nearer than standing still would: the
//! guard's fallbacks are tried, else the robot waits, stopped, and the
//! progress window restarts. The camera looks only ahead, and a person
//! who crossed in front of a turning robot walks on past its side, where
//! its corners swing (evaluation, hall with people crossing). In the
//! sweep disc everyone tracked counts `PeopleParams::radius_m` nearer
//! than where they stand: people sway and step while the corners swing.
//! Within `PeopleParams::near_walker_m` of a walker the speed is capped
//! at `PeopleParams::near_walker_mps`, from which the robot stops within
//! the straying the reach test allows them.
//! A walker's cells stay ordinary cells in the memory: forgetting them
//! out of view once they walked (they had gone on) raised the crossing
//! hall's success but let the robot turn into people who had stopped
//! beside it.

use nalgebra::Vector2;

use super::guard::arc_pose;
use super::{FollowParams, RobotState, StepInput};

impl RobotState {
    /// Whether someone is within `PeopleParams::yield_m` of the robot's
    /// centre — tracked now (standing or walking, where the tracker expects
    /// them), or seen there within `PeopleParams::recall_s` (a person beside
    /// the robot is out of the camera's view): a BLOCKED or NO_PROGRESS step
    /// is then WAITING for them (docs/design.md §4, "People in the way").
    /// People step aside and walk on; a way blocked by furniture does not
    /// clear by itself.
    pub(super) fn person_in_the_way(&self, input: &StepInput<'_>, p: &FollowParams) -> bool {
        let near = self.people.person_near(input.stamp, &input.pose, p.people.yield_m, &p.people);
        if near {
            tracing::debug!(stamp = input.stamp, "stopped for a person in the way");
        }
        near
    }

    /// Whether the command (v, ω), held for `PeopleParams::horizon_s`,
    /// brings the robot's body nearer a walker than their reach and nearer
    /// than standing still would (see the module docs). Logged at debug level.
    pub(super) fn people_closer(&self, input: &StepInput<'_>, v: f64, w: f64, p: &FollowParams) -> bool {
        const SAMPLES: usize = 10;
        let pp = &p.people;
        if v == 0.0 && w == 0.0 {
            return false;
        }
        let walkers = self.people.walkers_ahead(input.stamp, 0.0, &input.pose, pp).len();
        if walkers == 0 {
            return false;
        }
        // Distance from the footprint at (x, y, θ) to the point q.
        let gap = |q: &Vector2<f64>, x: f64, y: f64, th: f64| {
            let (s, c) = th.sin_cos();
            let (dx, dy) = (q.x - x, q.y - y);
            let (bx, by) = (c * dx + s * dy, -s * dx + c * dy);
            Vector2::new((bx.abs() - p.half_length_m).max(0.0), (by.abs() - p.half_width_m).max(0.0)).norm()
        };
        let mut moving = vec![f64::INFINITY; walkers];
        let mut still = vec![f64::INFINITY; walkers];
        for k in 0..=SAMPLES {
            let t = pp.horizon_s * k as f64 / SAMPLES as f64;
            let (x, y, th) = arc_pose(v, w, t);
            for (i, (q, reach)) in self.people.walkers_ahead(input.stamp, t, &input.pose, pp).iter().enumerate() {
                moving[i] = moving[i].min(gap(q, x, y, th) - reach);
                still[i] = still[i].min(gap(q, 0.0, 0.0, 0.0) - reach);
            }
        }
        let closer = moving.iter().zip(&still).any(|(m, s)| *m < 0.0 && *m < *s - 0.01);
        if closer {
            tracing::debug!(stamp = input.stamp, v, w, "waiting for a walking person");
        }
        closer
    }
}
