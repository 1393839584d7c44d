//! People tracked from the detector's boxes, in `odom`.
//!
//! The depth image alone cannot tell a person from a post: a cell is known to
//! move only where a frame a moment earlier saw free space behind it
//! (`control/memory.rs`), and a person first seen while the camera turns, or one
//! who walks beside the robot at the edge of the view, is never caught that
//! way. The detector's person boxes say what is a person; where the person
//! stands comes from the depth behind the box (`cloud.rs`), and this tracker
//! links those places from frame to frame by nearest neighbour within a gate
//! that grows with the time since the track was last seen. A track's
//! velocity is its displacement over its last `window_s` of sightings
//! (at least `min_sightings` of them, spanning at least `min_span_s`, so
//! that centroid noise between two frames does not make a walker, nor two
//! false positives a person; the detector misses a person at the edge of
//! the view in many frames, more while the camera turns, so the window is
//! long); faster than `walking_mps` it walks, and it counts as
//! a walker for `keep_s` after (a person turning round at the end of their
//! way, or pausing beside the robot, slows for a moment and walks on).
//!
//! What the local planner does with it (services/local-planner/README.md):
//! no command may bring the robot's body nearer a walker, carried on at
//! their velocity for `horizon_s`, than their radius — the camera looks only
//! ahead, and a person who crossed in front of a turning robot walks on past
//! its side. People change course, so the radius grows by `spread_mps` per
//! second since last seen (up to `spread_max_m`).

use std::collections::VecDeque;

use nalgebra::Vector2;
use vlnav_geometry::Pose2;

/// Tracking and prediction settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PeopleParams {
    /// A sighting joins a track within this distance of the track's
    /// predicted place, m, plus `gate_speed_mps` per second since the track
    /// was last seen (up to `gate_max_m`).
    pub gate_m: f64,
    pub gate_speed_mps: f64,
    pub gate_max_m: f64,
    /// Sightings kept per track, s of sensor time.
    pub window_s: f64,
    /// The shortest span of sightings a velocity is measured over, s.
    pub min_span_s: f64,
    /// Sightings within `window_s` before a track counts as a person at
    /// all: the detector's false positives (a person in 1 frame of 17 in
    /// the calibrated profile, anywhere in the image) seldom repeat in one
    /// place.
    pub min_sightings: usize,
    /// Faster than this a person walks, m/s (people walk at 0.8–1.5 m/s;
    /// a standing person's centroid wanders by a few cm between frames).
    pub walking_mps: f64,
    /// A track unseen for this long is dropped, s.
    pub keep_s: f64,
    /// How far ahead a walking person's course and the robot's command are
    /// carried on, s.
    pub horizon_s: f64,
    /// A person's radius for the reach test, m.
    pub radius_m: f64,
    /// How fast the reach grows with the time ahead, m/s, and its cap, m.
    pub spread_mps: f64,
    pub spread_max_m: f64,
    /// Within this distance of a walker (their predicted place, from the
    /// robot's centre) the robot drives no faster than `near_walker_mps`,
    /// m: what a walker (up to 1.5 m/s) and the robot (1.0 m/s) can close
    /// in `horizon_s`, plus the robot's half-length, the person's radius and
    /// `spread_max_m` — 2.5 + 0.495 + 0.3 + 0.3 ≈ 3.6 m.
    pub near_walker_m: f64,
    /// The speed near a walker, m/s: the fastest from which the robot,
    /// braking at `FollowParams::max_accel` (1 m/s²) after one frame
    /// (`FollowParams::nominal_period_s`, 0.2 s) of reaction, stops within
    /// `spread_max_m` (0.3 m), the margin the reach test allows a person to
    /// stray: v·0.2 + v²/2 = 0.3 gives 0.6 m/s. The camera looks only ahead
    /// and the detector misses people at the edge of the view, so a walker
    /// is often known only from a few frames; a robot at full speed beside
    /// them swings its corners faster than the tracker catches up
    /// (services/local-planner/README.md, "People").
    pub near_walker_mps: f64,
    /// A robot blocked (or making no progress) while someone it tracks is
    /// expected within this distance of its centre waits for them rather
    /// than counting as stuck, m: a person one step (0.8 m) beyond the
    /// robot's circumscribed radius (0.6 m), with their own radius and the
    /// straying the reach test allows, and as far again ahead, where a
    /// person in a doorway or a corridor takes every path (≈ 2.5 m).
    pub yield_m: f64,
    /// How long where a person was seen is recalled for `yield_m`, s: a
    /// person who stepped out of the camera's view beside the robot (the
    /// tracker drops them after `keep_s`) is most often still there,
    /// waiting for the robot as it waits for them.
    pub recall_s: f64,
    /// Near people the robot slows (`control/walkers.rs`): within
    /// `slow_gap_m` of clearance between its body and a person (their
    /// radius taken off) it drives and swings its corners no faster than
    /// `slow_mps`, and `slow_per_m` m/s faster per metre of clearance
    /// beyond. 0.3 m/s stops within one frame and 5 cm (1 m/s²), so a
    /// person who steps towards the robot meets a robot already standing.
    pub slow_gap_m: f64,
    pub slow_mps: f64,
    pub slow_per_m: f64,
    /// How long a person's place counts for slowing once out of view, s:
    /// a person beside the robot is out of the camera's ±43°; at a walking
    /// pace they are elsewhere after a few seconds. A place the camera
    /// looks at again and finds empty is forgotten at once.
    pub slow_recall_s: f64,
    /// A person last seen walking on a course that runs into the robot's
    /// body (within `radius_m` of it) is held, out of view, beside the body
    /// where that course passes nearest: people who meet a robot step
    /// aside and stand or squeeze past there (a 2.3 m corridor with four
    /// people pacing: one who passed the camera's edge stood 0.4 m from the
    /// robot's side for 15 s, and a turn in place swung the rear corner
    /// into them). Held within `beside_m` of the robot's centre — where the
    /// corners' swing (0.6 m), their radius and `touch_m` reach — they
    /// count for slowing and the touch rule for up to `beside_s` after the
    /// sighting instead of `slow_recall_s`, unless the camera looks there
    /// and finds no one (docs/design.md §4, "People in the way").
    pub beside_m: f64,
    pub beside_s: f64,
    /// No command may bring the body nearer a person than this clearance
    /// (and nearer than it is), m: the robot stops for them (WAITING).
    pub touch_m: f64,
    /// Where walkers alone turn the paths' choice more than this from the
    /// choice without them, the robot keeps behind them instead of going
    /// round (`control/behind.rs`), rad: about 30°, more than going round
    /// one person a few metres ahead takes.
    pub swerve_max_rad: f64,
}

impl Default for PeopleParams {
    fn default() -> Self {
        Self {
            gate_m: 0.5,
            gate_speed_mps: 1.5,
            gate_max_m: 1.5,
            window_s: 1.5,
            min_span_s: 0.4,
            min_sightings: 3,
            walking_mps: 0.35,
            keep_s: 2.0,
            horizon_s: 1.0,
            radius_m: 0.3,
            spread_mps: 0.5,
            spread_max_m: 0.3,
            near_walker_m: 3.6,
            near_walker_mps: 0.6,
            yield_m: 2.5,
            recall_s: 10.0,
            slow_gap_m: 0.5,
            slow_mps: 0.3,
            slow_per_m: 0.7,
            slow_recall_s: 4.0,
            beside_m: 1.2,
            beside_s: 30.0,
            touch_m: 0.2,
            swerve_max_rad: 0.5,
        }
    }
}

/// How long a person must be seen keeping still to count as standing, s:
/// most of the sightings' window (`PeopleParams::window_s`), so that
/// someone who just came into view, or paused for a step, is not.
const STANDING_SPAN_S: f64 = 1.0;

#[derive(Clone, Debug)]
struct Track {
    /// (stamp, odom position), oldest first.
    seen: VecDeque<(f64, Vector2<f64>)>,
    /// When the track was last measured walking.
    walked: Option<f64>,
}

impl Track {
    fn last(&self) -> (f64, Vector2<f64>) {
        *self.seen.back().expect("a track holds at least one sighting")
    }

    fn confirmed(&self, p: &PeopleParams) -> bool {
        self.seen.len() >= p.min_sightings
    }

    /// Velocity over the kept sightings, m/s (`None`: too few or too short a span).
    fn velocity(&self, p: &PeopleParams) -> Option<Vector2<f64>> {
        let (&(t0, a), &(t1, b)) = (self.seen.front()?, self.seen.back()?);
        (self.confirmed(p) && t1 - t0 >= p.min_span_s).then(|| (b - a) / (t1 - t0))
    }

    /// Whether the track walks now or did within `keep_s` before `stamp`.
    fn walker(&self, stamp: f64, p: &PeopleParams) -> bool {
        self.walked.is_some_and(|t| stamp - t <= p.keep_s)
    }

    /// Whether the track stands: seen for at least `STANDING_SPAN_S`,
    /// slower than `walking_mps` over its kept sightings, and not walking
    /// within `keep_s`.
    fn standing(&self, stamp: f64, p: &PeopleParams) -> bool {
        let (t0, t1) = (self.seen.front().map_or(0.0, |s| s.0), self.last().0);
        !self.walker(stamp, p)
            && t1 - t0 >= STANDING_SPAN_S
            && self.velocity(p).is_some_and(|v| v.norm() < p.walking_mps)
    }

    /// Where the track is expected at `stamp`: a walker carried on at their
    /// velocity, anyone else where last seen.
    fn predicted(&self, stamp: f64, p: &PeopleParams) -> Vector2<f64> {
        let (t, at) = self.last();
        let v = self.velocity(p).filter(|_| self.walker(stamp, p)).unwrap_or_else(Vector2::zeros);
        at + v * (stamp - t).max(0.0)
    }
}

/// The people one robot has seen lately.
#[derive(Clone, Debug, Default)]
pub struct Tracker {
    tracks: Vec<Track>,
    /// Where confirmed people were last seen, `odom`, for
    /// `PeopleParams::recall_s` (`beside_s` where held beside the robot):
    /// one per `RECALL_CELL_M` cell, the newest.
    recalled: Vec<Recalled>,
}

/// A confirmed person's sighting, kept after they left the view.
#[derive(Clone, Copy, Debug)]
struct Recalled {
    stamp: f64,
    at: Vector2<f64>,
    /// Their velocity where they walked then, else zero, m/s (`odom`).
    velocity: Vector2<f64>,
}

impl Recalled {
    /// Where someone whose course since the sighting runs into the robot's
    /// body (`pose`, `odom`; `half`: its half-length and half-width, m),
    /// them being `radius` m round, is held (`odom`): their course's point
    /// nearest the robot's centre (walked at most for the time since the
    /// sighting), moved out to `radius` from the body — beside it, where
    /// people who meet a robot and step aside stand or squeeze past.
    /// `None` for someone standing, walking away, or passing with room.
    fn held(&self, stamp: f64, pose: &Pose2, half: &Vector2<f64>, radius: f64) -> Option<Vector2<f64>> {
        let speed2 = self.velocity.norm_squared();
        if speed2 < 1e-9 {
            return None;
        }
        let nearest = (pose.position() - self.at).dot(&self.velocity) / speed2;
        let q = self.at + self.velocity * nearest.clamp(0.0, (stamp - self.stamp).max(0.0));
        let b = pose.inverse_transform(&q);
        let on_body = Vector2::new(b.x.clamp(-half.x, half.x), b.y.clamp(-half.y, half.y));
        let out = b - on_body;
        if out.norm() >= radius {
            return None;
        }
        let beside = if out.norm() > 1e-6 {
            on_body + out * (radius / out.norm())
        } else if half.x - b.x.abs() < half.y - b.y.abs() {
            Vector2::new((half.x + radius).copysign(b.x), b.y)
        } else {
            Vector2::new(b.x, (half.y + radius).copysign(b.y))
        };
        Some(pose.transform(&beside))
    }
}

/// Sightings recalled closer together than this are one, m.
const RECALL_CELL_M: f64 = 0.3;

impl Tracker {
    /// Adds this frame's people (`odom`; `None` where a box held no depth)
    /// and returns, per person, whether they walk now.
    pub fn update(&mut self, stamp: f64, people: &[Option<Vector2<f64>>], p: &PeopleParams) -> Vec<bool> {
        self.tracks.retain(|t| stamp - t.last().0 <= p.keep_s && t.last().0 <= stamp);
        // Nearest pairs first, each track and person used once.
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (i, at) in people.iter().enumerate() {
            let Some(at) = at else { continue };
            for (j, t) in self.tracks.iter().enumerate() {
                let gate = (p.gate_m + p.gate_speed_mps * (stamp - t.last().0)).min(p.gate_max_m);
                let d = (t.predicted(stamp, p) - at).norm();
                if d <= gate {
                    pairs.push((d, i, j));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut track_of = vec![None; people.len()];
        let mut taken = vec![false; self.tracks.len()];
        for (_, i, j) in pairs {
            if track_of[i].is_none() && !taken[j] {
                track_of[i] = Some(j);
                taken[j] = true;
            }
        }
        let mut walking = vec![false; people.len()];
        for (i, at) in people.iter().enumerate() {
            let Some(at) = *at else { continue };
            let j = match track_of[i] {
                Some(j) => j,
                None => {
                    self.tracks.push(Track { seen: VecDeque::new(), walked: None });
                    self.tracks.len() - 1
                }
            };
            let t = &mut self.tracks[j];
            t.seen.push_back((stamp, at));
            while t.seen.front().is_some_and(|&(s, _)| stamp - s > p.window_s) {
                t.seen.pop_front();
            }
            walking[i] = t.velocity(p).is_some_and(|v| v.norm() >= p.walking_mps);
            if walking[i] {
                t.walked = Some(stamp);
            }
        }
        let kept_s = p.recall_s.max(p.beside_s);
        self.recalled.retain(|r| stamp - r.stamp <= kept_s && r.stamp <= stamp);
        for t in self.tracks.iter().filter(|t| t.confirmed(p) && t.last().0 == stamp) {
            let at = t.last().1;
            let velocity = t.velocity(p).filter(|_| t.walker(stamp, p)).unwrap_or_else(Vector2::zeros);
            self.recalled.retain(|r| (r.at - at).norm() >= RECALL_CELL_M);
            self.recalled.push(Recalled { stamp, at, velocity });
        }
        walking
    }

    /// Whether a confirmed person was seen within `recall_s` before `stamp`
    /// within `range` of where the robot (`pose`) stands now, or is
    /// expected there (`people_at`).
    pub fn person_near(&self, stamp: f64, pose: &Pose2, range: f64, p: &PeopleParams) -> bool {
        let recalled =
            self.recalled.iter().any(|r| stamp - r.stamp <= p.recall_s && (r.at - pose.position()).norm() < range);
        recalled || self.people_at(stamp, pose, p).iter().any(|q| q.norm() < range)
    }

    /// Forgets the recalled places not sighted at `stamp` for which
    /// `looked_empty` holds (`odom`): the camera looked there this frame and
    /// no person stands there any more. Someone held where they met the
    /// robot (`pose`, its half-extents `half`) is looked for there.
    pub fn forget_looked_at(
        &mut self,
        stamp: f64,
        pose: &Pose2,
        half: &Vector2<f64>,
        p: &PeopleParams,
        looked_empty: impl Fn(&Vector2<f64>) -> bool,
    ) {
        self.recalled
            .retain(|r| r.stamp == stamp || !looked_empty(&r.held(stamp, pose, half, p.radius_m).unwrap_or(r.at)));
    }

    /// Where people are or may be at `stamp`, in `pose`'s frame (the robot's
    /// half-length and half-width `half`): everyone tracked (`people_at`),
    /// the places seen within `slow_recall_s`, and those held beside the
    /// robot within `beside_m` for `beside_s` (`Recalled::held`).
    pub fn people_around(&self, stamp: f64, pose: &Pose2, half: &Vector2<f64>, p: &PeopleParams) -> Vec<Vector2<f64>> {
        let robot = pose.position();
        let mut all = self.people_at(stamp, pose, p);
        all.extend(self.recalled.iter().filter_map(|r| {
            let age = stamp - r.stamp;
            match r.held(stamp, pose, half, p.radius_m) {
                Some(held) => ((held - robot).norm() <= p.beside_m && age <= p.beside_s).then_some(held),
                None => (age <= p.slow_recall_s).then_some(r.at),
            }
            .map(|q| pose.inverse_transform(&q))
        }));
        all
    }

    /// Every walker's expected place `ahead` s after `stamp`, carried on
    /// at their velocity (and no further than `keep_s` past their last
    /// sighting), in `pose`'s frame, with how near the robot's body may come
    /// to it: their radius plus how far they may have strayed.
    pub fn walkers_ahead(&self, stamp: f64, ahead: f64, pose: &Pose2, p: &PeopleParams) -> Vec<(Vector2<f64>, f64)> {
        self.tracks
            .iter()
            .filter(|t| t.walker(stamp, p))
            .map(|t| {
                let v = t.velocity(p).unwrap_or_else(Vector2::zeros);
                let (seen, at) = t.last();
                let dt = (stamp - seen + ahead).min(p.keep_s);
                (pose.inverse_transform(&(at + v * dt)), p.radius_m + (p.spread_mps * dt).min(p.spread_max_m))
            })
            .collect()
    }

    /// Where each person seen standing (`Track::standing`) was last seen,
    /// in `pose`'s frame.
    pub fn standing_at(&self, stamp: f64, pose: &Pose2, p: &PeopleParams) -> Vec<Vector2<f64>> {
        self.tracks.iter().filter(|t| t.standing(stamp, p)).map(|t| pose.inverse_transform(&t.last().1)).collect()
    }

    /// Whether a walker is expected within `range` of `pose` at `stamp`.
    pub fn walker_within(&self, stamp: f64, pose: &Pose2, range: f64, p: &PeopleParams) -> bool {
        self.walkers_ahead(stamp, 0.0, pose, p).iter().any(|(q, _)| q.norm() < range)
    }

    /// Where everyone seen within `keep_s` (and often enough to be sure) is expected at `stamp`, in
    /// `pose`'s frame (walkers carried on, others where last seen).
    pub fn people_at(&self, stamp: f64, pose: &Pose2, p: &PeopleParams) -> Vec<Vector2<f64>> {
        self.tracks
            .iter()
            .filter(|t| t.confirmed(p))
            .map(|t| pose.inverse_transform(&t.predicted(stamp.min(t.last().0 + p.keep_s), p)))
            .collect()
    }

    /// Moves every track by `f` (odometry re-anchored: the people keep their
    /// place relative to the robot).
    pub fn reanchor(&mut self, f: impl Fn(&Vector2<f64>) -> Vector2<f64>) {
        for t in &mut self.tracks {
            for (_, at) in &mut t.seen {
                *at = f(at);
            }
        }
        for r in &mut self.recalled {
            // A velocity is a difference of places: moved as one.
            let (at, ahead) = (f(&r.at), f(&(r.at + r.velocity)));
            r.velocity = ahead - at;
            r.at = at;
        }
    }

    pub fn clear(&mut self) {
        self.tracks.clear();
        self.recalled.clear();
    }

    pub fn len(&self) -> usize {
        self.tracks.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tracks.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> PeopleParams {
        PeopleParams::default()
    }

    /// The Husky's half-length and half-width, m.
    fn half() -> Vector2<f64> {
        crate::control::FollowParams::default().half_extents()
    }

    #[test]
    fn a_person_who_walks_is_told_from_one_who_stands() {
        let mut t = Tracker::default();
        let mut walker = Vec::new();
        let mut stander = Vec::new();
        for k in 0..10 {
            let s = f64::from(k) * 0.2;
            // One walks across at 1 m/s; the other stands, their centroid
            // wandering by ±4 cm from frame to frame.
            let jitter = if k % 2 == 0 { 0.04 } else { -0.04 };
            let w = t.update(s, &[Some(Vector2::new(3.0, -1.0 + s)), Some(Vector2::new(2.0, 1.5 + jitter))], &p());
            walker.push(w[0]);
            stander.push(w[1]);
        }
        assert_eq!(t.len(), 2, "two people, two tracks");
        assert!(walker[..2].iter().all(|w| !w), "not walking before a velocity is measured: {walker:?}");
        assert!(walker[2..].iter().all(|w| *w), "walking once three sightings span 0.4 s: {walker:?}");
        assert!(stander.iter().all(|w| !w), "the standing person never walks: {stander:?}");
    }

    #[test]
    fn a_walker_is_carried_on_until_dropped() {
        let mut t = Tracker::default();
        let robot = Pose2::new(0.0, 0.0, 0.0);
        // Crossing 1.2 m in front of the robot, from its right to its left, at 1.1 m/s.
        for k in 0..5 {
            let s = f64::from(k) * 0.2;
            t.update(s, &[Some(Vector2::new(1.2, -2.0 + 1.1 * s))], &p());
        }
        // Last seen at (1.2, −1.12) at 0.8 s; half a second later, unseen:
        // 0.55 m on, and 0.25 m of straying on top of their radius.
        let ahead = t.walkers_ahead(1.0, 0.3, &robot, &p());
        assert_eq!(ahead.len(), 1);
        let (at, reach) = ahead[0];
        assert!((at - Vector2::new(1.2, -0.57)).norm() < 0.02, "at {at:?}");
        assert!((reach - 0.55).abs() < 1e-9, "reach {reach}");
        // Carried on no further than 2 s past the last sighting.
        let (at, reach) = t.walkers_ahead(2.5, 1.0, &robot, &p())[0];
        assert!((at - Vector2::new(1.2, 1.08)).norm() < 0.02 && (reach - 0.6).abs() < 1e-9, "{at:?} {reach}");
        t.update(3.0, &[], &p());
        assert!(t.is_empty(), "unseen for longer than keep_s");
    }

    #[test]
    fn a_standing_person_is_no_walker_however_near() {
        let mut t = Tracker::default();
        for k in 0..10 {
            t.update(f64::from(k) * 0.2, &[Some(Vector2::new(0.9, 0.0))], &p());
        }
        assert!(t.walkers_ahead(2.0, 0.5, &Pose2::new(0.0, 0.0, 0.0), &p()).is_empty());
    }

    #[test]
    fn two_people_crossing_keep_their_own_tracks() {
        let mut t = Tracker::default();
        let mut last = Vec::new();
        for k in 0..10 {
            let s = f64::from(k) * 0.2;
            // They walk towards each other along x, 0.8 m apart across.
            last = t.update(s, &[Some(Vector2::new(1.0 + s, 0.4)), Some(Vector2::new(4.0 - s, -0.4))], &p());
        }
        assert_eq!(t.len(), 2);
        assert_eq!(last, vec![true, true]);
    }

    #[test]
    fn a_person_who_stepped_out_of_view_is_recalled_near_for_a_while() {
        let (pp, pose) = (p(), Pose2::new(0.0, 0.0, 0.0));
        let mut t = Tracker::default();
        for k in 0..5 {
            t.update(0.2 * f64::from(k), &[Some(Vector2::new(1.0, 0.5))], &pp);
        }
        assert!(t.person_near(0.8, &pose, pp.yield_m, &pp));
        // Out of view (no sightings): the track goes after keep_s, the
        // recalled place stays for recall_s.
        for k in 5..=50 {
            t.update(0.2 * f64::from(k), &[], &pp);
        }
        assert!(t.people_at(10.0, &pose, &pp).is_empty());
        assert!(t.person_near(10.0, &pose, pp.yield_m, &pp));
        assert!(!t.person_near(10.0, &Pose2::new(-3.0, 0.0, 0.0), pp.yield_m, &pp), "farther than yield_m");
        t.update(11.0, &[], &pp);
        assert!(!t.person_near(11.0, &pose, pp.yield_m, &pp), "forgotten after recall_s");
    }

    #[test]
    fn a_recalled_place_looked_at_and_empty_is_forgotten_one_sighted_now_is_kept() {
        let (pp, pose) = (p(), Pose2::new(0.0, 0.0, 0.0));
        let mut t = Tracker::default();
        for k in 0..5 {
            t.update(0.2 * f64::from(k), &[Some(Vector2::new(1.0, 0.5))], &pp);
        }
        // Seen this frame: kept whatever the check says.
        t.forget_looked_at(0.8, &pose, &half(), &pp, |_| true);
        assert!(t.person_near(0.8, &pose, pp.yield_m, &pp));
        t.update(1.0, &[], &pp);
        // Not looked at: kept.
        t.forget_looked_at(1.0, &pose, &half(), &pp, |_| false);
        assert_eq!(t.people_around(1.0, &pose, &half(), &pp).len(), 2, "the track and its recalled place");
        t.forget_looked_at(1.0, &pose, &half(), &pp, |_| true);
        assert_eq!(t.people_around(1.0, &pose, &half(), &pp).len(), 1, "the track only");
    }

    #[test]
    fn a_walker_whose_course_runs_into_the_robot_is_held_beside_it() {
        let (pp, pose) = (p(), Pose2::new(0.0, 0.0, 0.0));
        let walk = |y: f64| {
            let mut t = Tracker::default();
            // Coming towards the robot at 1 m/s, last seen 1.2 m ahead at
            // the camera's edge, then unseen for 12 s.
            for k in 0..5 {
                let s = 0.2 * f64::from(k);
                t.update(s, &[Some(Vector2::new(2.0 - s, y))], &pp);
            }
            for k in 5..=60 {
                t.update(0.2 * f64::from(k), &[], &pp);
            }
            t
        };
        // 0.55 m to the right of the centre line: within their radius of
        // the body. Held beside it where the course passes nearest, not
        // 11 m behind; kept when the camera finds where they were last
        // seen empty; gone after beside_s.
        let mut met = walk(-0.55);
        let around = met.people_around(12.0, &pose, &half(), &pp);
        assert_eq!(around.len(), 1, "{around:?}");
        assert!((around[0] - Vector2::new(0.0, -0.635)).norm() < 1e-6, "{around:?}");
        met.forget_looked_at(12.0, &pose, &half(), &pp, |q| q.x > 0.5);
        assert_eq!(met.people_around(12.0, &pose, &half(), &pp).len(), 1);
        assert!(met.people_around(pp.beside_s + 1.0, &pose, &half(), &pp).is_empty());
        // Looked at where held and nobody there: forgotten.
        met.forget_looked_at(12.0, &pose, &half(), &pp, |q| q.x.abs() < 0.1);
        assert!(met.people_around(12.0, &pose, &half(), &pp).is_empty());
        // 0.8 m to the right: they pass with room, and count only where
        // last seen, for slow_recall_s.
        let passed = walk(-0.8);
        assert!(passed.people_around(12.0, &pose, &half(), &pp).is_empty());
        // Someone walking away is not held.
        let mut away = Tracker::default();
        for k in 0..5 {
            let s = 0.2 * f64::from(k);
            away.update(s, &[Some(Vector2::new(1.0 + s, -0.5))], &pp);
        }
        away.update(1.2, &[], &pp);
        away.forget_looked_at(1.2, &pose, &half(), &pp, |q| q.x > 0.5);
        assert_eq!(away.people_around(1.2, &pose, &half(), &pp).len(), 1, "the track only, carried on");
    }
}
