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
//! Near anyone tracked, or seen within `PeopleParams::slow_recall_s` and
//! not looked at since, every command is slowed with the clearance
//! (`PeopleParams::slow_gap_m`): out of the camera's view beside a turning
//! robot, a person is where its corners swing.
//! A walker's cells stay ordinary cells in the memory: forgetting them
//! out of view once they walked (they had gone on) raised the crossing
//! hall's success but let the robot turn into people who had stopped
//! beside it.

use nalgebra::Vector2;

use super::guard::arc_pose;
use super::{FollowParams, RobotState, StepInput};

/// How far ahead a command is carried on for whether it touches a
/// person, s: one frame and the stop from the slow speed near people.
const TOUCH_HORIZON_S: f64 = 0.5;

/// A command after slowing near people, and whether it would touch one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct NearPeople {
    pub(super) v: f64,
    pub(super) w: f64,
    pub(super) touches: bool,
}

/// Distance from the footprint at (x, y, θ) (`base_link` of this frame) to
/// the point `q`, m: 0 inside it.
fn footprint_gap(q: &Vector2<f64>, x: f64, y: f64, th: f64, p: &FollowParams) -> f64 {
    let (s, c) = th.sin_cos();
    let (dx, dy) = (q.x - x, q.y - y);
    let (bx, by) = (c * dx + s * dy, -s * dx + c * dy);
    Vector2::new((bx.abs() - p.half_length_m).max(0.0), (by.abs() - p.half_width_m).max(0.0)).norm()
}

impl RobotState {
    /// The command slowed near people (`PeopleParams::slow_gap_m`): for
    /// each person tracked or recalled (`Tracker::people_around`), the
    /// clearance between the body and them caps the speed toward them
    /// (ahead of the rear axle driving forward, behind the front one
    /// backing) and the corners' speed while turning; (v, ω) are scaled
    /// together, so the arc the guard passed is kept. A command that,
    /// slowed and held for `TOUCH_HORIZON_S`, brings the body nearer a person than
    /// `PeopleParams::touch_m` and nearer than it is now `touches`: the
    /// robot stops for them instead (a person who stepped against a
    /// stopped robot, which then crept on into them).
    pub(super) fn slow_near_people(&self, input: &StepInput<'_>, v: f64, w: f64, p: &FollowParams) -> NearPeople {
        const SAMPLES: usize = 5;
        let pp = &p.people;
        let mut near = NearPeople { v, w, touches: false };
        if v == 0.0 && w == 0.0 {
            return near;
        }
        let corner = p.half_length_m.hypot(p.half_width_m);
        let gap = |q: &Vector2<f64>, x: f64, y: f64, th: f64| footprint_gap(q, x, y, th, p) - pp.radius_m;
        let half = p.half_extents();
        let people = self.people.people_around(input.stamp, &input.pose, &half, pp);
        let mut scale: f64 = 1.0;
        for q in &people {
            let cap = pp.slow_mps + pp.slow_per_m * (gap(q, 0.0, 0.0, 0.0) - pp.slow_gap_m).max(0.0);
            let toward = (v > 0.0 && q.x > -p.half_length_m) || (v < 0.0 && q.x < p.half_length_m);
            if toward && v.abs() > cap {
                scale = scale.min(cap / v.abs());
            }
            if w.abs() * corner > cap {
                scale = scale.min(cap / (w.abs() * corner));
            }
        }
        (near.v, near.w) = (v * scale, w * scale);
        near.touches = people.iter().any(|q| {
            let soonest = (0..=SAMPLES)
                .map(|k| {
                    let (x, y, th) = arc_pose(near.v, near.w, TOUCH_HORIZON_S * k as f64 / SAMPLES as f64);
                    gap(q, x, y, th)
                })
                .fold(f64::INFINITY, f64::min);
            soonest < pp.touch_m && soonest < gap(q, 0.0, 0.0, 0.0) - 0.005
        });
        if near.touches {
            tracing::debug!(stamp = input.stamp, v, w, "stopped: the command would touch a person");
        } else if scale < 1.0 {
            tracing::debug!(stamp = input.stamp, v, w, scale, "slowed near a person");
        }
        near
    }

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
        let gap = |q: &Vector2<f64>, x: f64, y: f64, th: f64| footprint_gap(q, x, y, th, p);
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

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;

    use super::super::test_support::turn_in_place_to;
    use super::super::{FollowParams, RobotState};
    use super::NearPeople;
    use crate::cloud::ObstacleCloud;

    /// A robot at the origin that saw a person standing at `at` (`odom`)
    /// in frames up to `seen_until` s.
    fn saw(at: Vector2<f64>, seen_until: f64, p: &FollowParams) -> RobotState {
        let mut state = RobotState::default();
        for k in 0..5 {
            state.people.update(seen_until - 0.2 * f64::from(4 - k), &[Some(at)], &p.people);
        }
        state
    }

    #[test]
    fn near_a_person_the_robot_drives_and_turns_slowly() {
        let p = FollowParams::default();
        let empty = ObstacleCloud::default();
        let input = turn_in_place_to(1.0, &empty);
        let corner = p.half_length_m.hypot(p.half_width_m);
        // A metre to the right: the turn swings a corner at most
        // `slow_mps`, the forward command is slowed as much, its arc kept.
        let beside = saw(Vector2::new(0.0, -1.0), 0.0, &p);
        let near = beside.slow_near_people(&input, 0.0, 1.5, &p);
        assert_eq!(near.v, 0.0);
        assert!((near.w * corner - p.people.slow_mps).abs() < 1e-9, "corner speed {}", near.w * corner);
        assert!(!near.touches);
        let near = beside.slow_near_people(&input, 1.0, 0.5, &p);
        assert!(near.v <= p.people.slow_mps + 1e-9 && (near.w / near.v - 0.5).abs() < 1e-9, "the arc kept: {near:?}");
        // Behind the robot, driving away: no slower; backing towards them: slow.
        let behind = saw(Vector2::new(-1.2, 0.0), 0.0, &p);
        assert_eq!(behind.slow_near_people(&input, 1.0, 0.0, &p), NearPeople { v: 1.0, w: 0.0, touches: false });
        assert!(behind.slow_near_people(&input, -0.5, 0.0, &p).v > -0.5);
        // Three and a half metres off: no slower.
        let far = saw(Vector2::new(3.5, 0.0), 0.0, &p);
        assert_eq!(far.slow_near_people(&input, 1.0, 0.3, &p), NearPeople { v: 1.0, w: 0.3, touches: false });
    }

    #[test]
    fn a_command_that_would_touch_a_person_is_stopped_one_that_draws_away_is_not() {
        let p = FollowParams::default();
        let empty = ObstacleCloud::default();
        let input = turn_in_place_to(1.0, &empty);
        // A person who stepped against the robot's front (crossing hall):
        // creeping on into them touches; backing away does not.
        let against = saw(Vector2::new(0.76, 0.05), 0.0, &p);
        assert!(against.slow_near_people(&input, 0.15, -0.3, &p).touches);
        assert!(!against.slow_near_people(&input, -0.25, 0.0, &p).touches);
        // 0.9 m ahead of the front: slowed, not stopped.
        let ahead = saw(Vector2::new(1.7, 0.0), 0.0, &p);
        let near = ahead.slow_near_people(&input, 1.0, 0.0, &p);
        assert!(!near.touches && near.v < 1.0 && near.v >= p.people.slow_mps, "{near:?}");
    }

    #[test]
    fn a_person_out_of_view_slows_the_robot_until_recall_runs_out_or_the_camera_looks() {
        let p = FollowParams::default();
        let empty = ObstacleCloud::default();
        let input = |stamp: f64| {
            let mut i = turn_in_place_to(1.0, &empty);
            i.stamp = stamp;
            i
        };
        let unseen = |state: &mut RobotState, from: f64, until: f64| {
            for k in (from / 0.2).round() as i32 + 1..=(until / 0.2).round() as i32 {
                state.people.update(0.2 * f64::from(k), &[], &p.people);
            }
        };
        // Standing beside the robot: still slowed after the track is
        // dropped (keep_s), no more after slow_recall_s.
        let at = Vector2::new(0.2, -0.7);
        let mut state = saw(at, 0.0, &p);
        unseen(&mut state, 0.0, 3.0);
        assert!(state.people.people_at(3.0, &input(3.0).pose, &p.people).is_empty());
        assert!(state.slow_near_people(&input(3.0), 0.0, 1.5, &p).w < 1.0);
        assert_eq!(state.slow_near_people(&input(p.people.slow_recall_s + 0.1), 0.0, 1.5, &p).w, 1.5);
        // Last seen at the camera's edge walking at 0.6 m/s on a course into
        // the robot's right side: held beside its middle for beside_s,
        // where a turn either way brings the body nearer; driving on does
        // not.
        let mut met = RobotState::default();
        for k in 0..5 {
            let s = 0.2 * f64::from(k);
            met.people.update(s, &[Some(Vector2::new(1.6 - 0.6 * s, -0.55))], &p.people);
        }
        unseen(&mut met, 0.8, 10.0);
        assert!(met.slow_near_people(&input(10.0), 0.0, 1.5, &p).touches);
        assert!(met.slow_near_people(&input(10.0), 0.0, -1.5, &p).touches);
        let on = met.slow_near_people(&input(10.0), 0.5, 0.0, &p);
        assert!(!on.touches && on.v <= p.people.slow_mps + 1e-9, "{on:?}");
        met.people.update(p.people.beside_s + 1.0, &[], &p.people);
        assert_eq!(met.slow_near_people(&input(p.people.beside_s + 1.0), 0.0, -1.5, &p).w, -1.5);
        // Looked at again (after the track went) and nobody there: the
        // recalled place is forgotten at once.
        let mut looked = saw(at, 0.0, &p);
        looked.people.update(2.5, &[], &p.people);
        assert!(looked.slow_near_people(&input(2.5), 0.0, 1.5, &p).w < 1.0);
        let half = p.half_extents();
        looked.people.forget_looked_at(2.5, &input(2.5).pose, &half, &p.people, |q| (q - at).norm() < 0.1);
        assert_eq!(looked.slow_near_people(&input(2.5), 0.0, 1.5, &p).w, 1.5);
    }
}
