//! FIND: which box is the target — the class vote on an unnamed fixed
//! candidate, a named person's identity, the reference an instance is
//! described by, where a confirmed target projects — and when it is
//! confirmed.

use nalgebra::{Vector2, Vector3};
use vlnav_geometry::camera::{Camera, Projector};
use vlnav_geometry::{Pose2, wrap_angle};

use super::landmarks::remember_landmarks;
use super::size::fits_class;
use super::{Explore, Mission, Next, OFF_COURSE_RAD, Pending, REFERENCE_PLACES, REFERENCE_SAME_M, Request, bearing};
use crate::config::ExecutorParams;
use crate::executor::model::*;

/// A sighting of an unconfirmed candidate counts for it only if it puts
/// the target within this of the candidate's fused position, m (the D455's
/// single-frame error is 0.5 m at 10 m; docs/perception.md).
const CONSISTENT_M: f64 = 1.0;
/// The class vote on an unnamed fixed candidate, counted over every frame
/// it has been watched: it is confirmed once its sightings are at least this
/// many times the frames another class's box stood where it projects, and
/// dropped once those frames (at least `confirm_frames`) are this many times
/// its sightings; in between it is watched on. The shipped detector calls a
/// bicycle a motorcycle, and a suitcase a backpack, in one frame of five
/// (deploy/perception/nanodet-realistic.toml): a bare majority over one
/// window of 8 frames goes the wrong way in about one window of 18, and a
/// robot watching an object for a few seconds sees many windows.
const VOTE_MARGIN: u32 = 2;
/// A candidate is dropped only once the other class's frames also outnumber
/// its sightings by this many. With a confusion rate c each label moves the
/// odds by (1 − c)/c, 4 at the shipped detector's 0.2; three net labels put
/// them at 64 : 1 against the candidate. A margin of two (16 : 1) dropped a
/// real chair labelled "couch" in three of its first four sightings, and
/// its place is ignored for the rest of the step (evaluation, indoor,
/// trial 18; campus, trial 47, a bench labelled "chair").
const REJECT_NET: u32 = 3;
/// A target with a reference: another instance takes the candidate's place
/// only when its footprint stands this much nearer a reference's (metres on
/// the ground), so two about equally near do not take turns.
const REFERENCE_MARGIN_M: f64 = 0.5;

/// A box of another class centred where the candidate projects stands in
/// front of it, not where it is, when the floor under the box is nearer the
/// robot than this share of the candidate's range. The floor point under a
/// box's bottom edge moves by range² / (f · camera height) per pixel (0.25
/// m at 3 m, 1.6 m at 8 m for the evaluation's 160 × 120 frames), so only a
/// clearly nearer box counts as in front: a person walking between the
/// robot and a stop sign hid the sign, and was taken for another class's
/// vote that dropped it (generated worlds, docs/evaluation.md).
const OCCLUDER_SHARE: f64 = 0.6;

/// A candidate stands behind where the route's last MOVE ended when it lies
/// more than this behind that point along the MOVE's course, m: the slack
/// a MOVE ends with (up to 0.5 m) and the fused position's error.
const BEHIND_M: f64 = 1.0;

/// A sighting this close to an outvoted candidate's place is that object, m.
const REJECTED_M: f64 = 0.75;

/// A target described by a reference ("the bicycle next to the stop sign")
/// stands next to it when its fused position is within this of a place
/// where a box of the reference's class stood, m: the two objects' half
/// sizes (up to 1 m each), the gap people still call "next to", and the
/// footprint's and the fused position's own errors at 10 m (0.5 m each;
/// docs/perception.md).
const NEXT_TO_M: f64 = 3.0;
/// How long the search for an instance next to its reference may go on
/// once one was set aside, sensor s: a look-around (12 turns, up to 4 s
/// each) and one search leg with its fan. The reference is often just too
/// small for the detector at that range (a dining table is found in no
/// frame beyond about 2.5 m; docs/perception.md), and a user would rather
/// the robot went to the one it saw than searched on for minutes.
const REFERENCE_SEARCH_S: f64 = 60.0;

/// A candidate that passed the class vote with no box of the reference's
/// class next to it: what it takes to go to it after all.
#[derive(Clone, Debug)]
pub(super) struct SetAside {
    pub(super) fused: Vector3<f64>,
    pub(super) goal: Goal,
    pub(super) detection: Detection,
    pub(super) range_m: f64,
    /// Set aside for standing behind where the route's last MOVE ended,
    /// not for want of its reference.
    pub(super) behind: bool,
}

#[derive(Debug)]
pub(super) struct FindRun {
    pub(super) track_key: String,
    pub(super) class_id: i32,
    pub(super) person: String,
    pub(super) target: String,
    /// The class of the object the target was described by, if any, and
    /// where (odom, on the floor) boxes of that class have stood this step.
    pub(super) reference: Option<i32>,
    pub(super) reference_at: Vec<Vector2<f64>>,
    pub(super) d_s: f64,
    pub(super) moving: bool,
    /// FOLLOW: how long to follow once the target is confirmed, s (the
    /// plan's duration, or the configured default when it gives none).
    pub(super) follow_s: f64,
    /// Sightings of the last frames, newest in bit 0.
    pub(super) recent: u64,
    /// The class vote on the current candidate, over every frame it has
    /// been watched: its accepted sightings, and the frames in which
    /// another class's box (and none of the target's) stood where it projects.
    pub(super) votes_for: u32,
    pub(super) votes_against: u32,
    /// Frames the current candidate has been watched for (the vote needs a
    /// full window before it may confirm).
    pub(super) watched: u32,
    /// Places (odom) of candidates another class outvoted.
    pub(super) rejected: Vec<Vector2<f64>>,
    /// Places (odom) of candidates that passed the vote with no box of the
    /// reference's class next to them: set aside while the search looks for
    /// one that has, and taken when it finds none.
    pub(super) set_aside: Vec<SetAside>,
    /// When the first candidate was set aside (sensor time).
    pub(super) set_aside_since: Option<f64>,
    /// The search found no instance next to its reference (or none ahead
    /// of where the route's MOVE ended): the nearest one set aside is the
    /// target after all.
    pub(super) reference_waived: bool,
    /// The route's course (odom heading), while the robot has not yet
    /// looked along it: the step began facing more than a scan turn off it
    /// (a MOVE that went round something), and an instance off the course
    /// is confirmed only after the view along it showed none.
    pub(super) course_first: Option<f64>,
    /// The goal of the route's last MOVE (`odom`; its heading is the
    /// MOVE's course), when a MOVE came right before this step: "move 13
    /// meters forward, then stop before the backpack" means a backpack ahead
    /// of that point, and one behind it is set aside while the search looks
    /// ahead.
    pub(super) route_end: Option<Pose2>,
    /// Where an earlier step saw an object of this class ([`remembered`]),
    /// until the exploration has driven toward it.
    pub(super) revisit: Option<Vector2<f64>>,
    /// Tracks started for this step (a new one after each rejection).
    pub(super) tracks: u32,
    pub(super) confirmed: bool,
    pub(super) goal: Option<Goal>,
    /// The fused target (odom) of the latest accepted observation.
    pub(super) fused: Option<Vector3<f64>>,
    pub(super) last_center: Option<(f32, f32)>,
    pub(super) unseen: u32,
    pub(super) last_seen: Option<f64>,
    /// FOLLOW: the target's walking velocity (odom, m/s), from its fused
    /// positions, and the fused position and stamp it was last measured from.
    pub(super) velocity: Option<Vector2<f64>>,
    pub(super) velocity_from: Option<(f64, Vector3<f64>)>,
    pub(super) follow_until: Option<f64>,
    pub(super) explore: Explore,
    /// The heading the exploration searches along, the first look-around's
    /// origin (the route's course, where the robot came from a MOVE): a
    /// search leg with no lead goes that way, wherever the last leg ended
    /// facing.
    pub(super) search_heading: Option<f64>,
    /// The frontier the local planner last reported during this FIND's
    /// exploration (`odom`): a search leg with no lead drives there.
    pub(super) frontier: Vec<[f64; 2]>,
}

impl FindRun {
    /// An unnamed fixed target: put to the class vote and checked for
    /// consistent sightings before it is confirmed.
    pub(super) fn put_to_vote(&self) -> bool {
        self.person.is_empty() && !self.moving
    }

    /// The target is described by an object of another class, and only an
    /// instance next to one may be confirmed.
    fn needs_reference(&self) -> bool {
        self.put_to_vote() && !self.reference_waived && self.reference.is_some_and(|c| c != self.class_id)
    }

    /// A box of the reference's class has stood within `NEXT_TO_M` of `at`.
    fn next_to_reference(&self, at: &Vector2<f64>) -> bool {
        self.reference_at.iter().any(|r| (r - at).norm() <= NEXT_TO_M)
    }

    /// `at` is where a candidate set aside stood: one behind where the
    /// route's MOVE ended, or one with still no reference seen next to it
    /// (until the search is over and the set-aside ones may be taken).
    fn set_aside_at(&self, at: &Vector2<f64>) -> bool {
        let near = |s: &&SetAside| (s.fused.xy() - at).norm() <= CONSISTENT_M;
        !self.reference_waived
            && self
                .set_aside
                .iter()
                .filter(near)
                .any(|s| s.behind || (self.needs_reference() && !self.next_to_reference(at)))
    }

    /// `at` lies behind where the route's last MOVE ended, along its course.
    pub(super) fn behind_route_end(&self, at: &Vector2<f64>) -> bool {
        self.route_end
            .is_some_and(|end| (at - end.position()).dot(&Vector2::new(end.theta.cos(), end.theta.sin())) < -BEHIND_M)
    }

    /// The search for an instance next to its reference has had its time
    /// (`REFERENCE_SEARCH_S` since the first was set aside, at `stamp`),
    /// and there is one to go back to.
    pub(super) fn reference_search_over(&self, stamp: f64) -> bool {
        self.can_waive() && self.set_aside_since.is_some_and(|t| stamp - t >= REFERENCE_SEARCH_S)
    }

    /// A candidate was set aside for want of its reference, and the
    /// reference has not been waived yet.
    pub(super) fn can_waive(&self) -> bool {
        !self.reference_waived && !self.set_aside.is_empty()
    }

    /// Waives the reference: the candidate set aside nearest `from` is the
    /// target after all (`None` when there is none).
    fn waive_reference(&mut self, from: &Pose2) -> Option<SetAside> {
        if !self.can_waive() {
            return None;
        }
        let here = from.position();
        let i = (0..self.set_aside.len()).min_by(|&i, &j| {
            let d = |k: usize| (self.set_aside[k].fused.xy() - here).norm();
            d(i).total_cmp(&d(j))
        })?;
        self.reference_waived = true;
        Some(self.set_aside.swap_remove(i))
    }

    /// A candidate is under the vote: sighted, not yet confirmed.
    fn under_vote(&self) -> bool {
        self.put_to_vote() && !self.confirmed && self.votes_for > 0
    }

    /// Drops the current candidate: its votes and the subgoal estimator's
    /// track (the next sighting starts a new one).
    fn new_track(&mut self) {
        self.tracks += 1;
        self.track_key = format!("{}#{}", self.track_key.split('#').next().unwrap_or_default(), self.tracks);
        (self.recent, self.votes_for, self.votes_against, self.watched, self.last_center, self.goal) =
            (0, 0, 0, 0, None, None);
    }
}

/// Where a target fixed in `odom` appears in this frame.
#[derive(Clone, Copy, Debug, PartialEq)]
enum TargetView {
    /// At this pixel.
    At(f32, f32),
    /// Behind the camera or outside the image: any box seen is something else.
    OutOfView,
}

/// The pixel `(u, v)` and depth at which an `odom` point is seen from
/// `pose`, if in front of the camera.
pub(super) fn pixel_from(camera: &Camera, pose: &Pose2, target: &Vector3<f64>) -> Option<(f64, f64, f64)> {
    let base = pose.inverse_transform(&target.xy());
    Projector::new(camera).pixel_of(Vector3::new(base.x, base.y, target.z))
}

/// `None` when the frame has no camera model to predict with.
fn target_view(frame: &Frame, target: &Vector3<f64>) -> Option<TargetView> {
    let camera = frame.camera.as_ref()?;
    let (w, h) = (camera.width as f64, camera.height as f64);
    Some(match pixel_from(camera, &frame.pose, target) {
        Some((u, v, _)) if (0.0..w).contains(&u) && (0.0..h).contains(&v) => TargetView::At(u as f32, v as f32),
        _ => TargetView::OutOfView,
    })
}

/// The box showing the target predicted at `(u, v)`: the nearest whose
/// extent, grown by half its size on every side, holds the prediction.
fn box_at(boxes: &[Detection], u: f32, v: f32) -> Option<&Detection> {
    boxes
        .iter()
        .filter(|b| {
            let (mx, my) = ((b.x_max - b.x_min) / 2.0, (b.y_max - b.y_min) / 2.0);
            (b.x_min - mx..=b.x_max + mx).contains(&u) && (b.y_min - my..=b.y_max + my).contains(&v)
        })
        .min_by(|a, b| {
            let d = |x: &Detection| (x.center().0 - u).hypot(x.center().1 - v);
            d(a).total_cmp(&d(b))
        })
}

/// `(u, v)` lies in the middle of `b` (its central half in each direction):
/// the box shows what stands there, not a neighbour beside it.
fn centred_on(b: &Detection, u: f32, v: f32) -> bool {
    let (qx, qy) = ((b.x_max - b.x_min) / 4.0, (b.y_max - b.y_min) / 4.0);
    (b.x_min + qx..=b.x_max - qx).contains(&u) && (b.y_min + qy..=b.y_max - qy).contains(&v)
}

/// Where an object stands on the floor (`odom`, metres): the ground under
/// the middle of its box's bottom edge, seen from this frame's pose.
fn footprint(frame: &Frame, projector: &Projector, b: &Detection) -> Option<Vector2<f64>> {
    let u = (b.x_min + b.x_max) as f64 / 2.0;
    projector.ground_point(u, b.y_max as f64).map(|g| frame.pose.transform(&g.xy()))
}

/// `b` stands in front of `target` (`odom`), hiding it, rather than where
/// it is: the floor under the box is nearer the robot than
/// `OCCLUDER_SHARE` of the target's range.
fn hides(frame: &Frame, b: &Detection, target: &Vector3<f64>) -> bool {
    let Some(camera) = frame.camera.as_ref() else { return false };
    let robot = Vector2::new(frame.pose.x, frame.pose.y);
    footprint(frame, &Projector::new(camera), b)
        .is_some_and(|at| (at - robot).norm() < OCCLUDER_SHARE * (target.xy() - robot).norm())
}

/// Where this frame's boxes stand, with their class (odom footprints; none
/// without a camera model, or for a box whose bottom is not below the horizon).
fn places_of(frame: &Frame, boxes: &[Detection]) -> Vec<(i32, Vector2<f64>)> {
    let Some(camera) = frame.camera.as_ref() else { return Vec::new() };
    let projector = Projector::new(camera);
    boxes.iter().filter_map(|b| footprint(frame, &projector, b).map(|at| (b.class_id, at))).collect()
}

/// The index of the box whose centre is nearest `(cx, cy)`, the instance
/// tracked so far.
fn nearest_to(boxes: &[Detection], (cx, cy): (f32, f32)) -> Option<usize> {
    let d = |b: &Detection| (b.center().0 - cx).hypot(b.center().1 - cy);
    (0..boxes.len()).min_by(|&i, &j| d(&boxes[i]).total_cmp(&d(&boxes[j])))
}

/// Remembers where reference boxes stood.
fn remember_reference(f: &mut FindRun, places: Vec<Vector2<f64>>) {
    for at in places {
        f.reference_at.retain(|p| (p - at).norm() > REFERENCE_SAME_M);
        if f.reference_at.len() == REFERENCE_PLACES {
            f.reference_at.remove(0);
        }
        f.reference_at.push(at);
    }
}

/// An unconfirmed target with a reference seen this step (in this frame or
/// an earlier one): the instance in this frame whose footprint stands
/// nearest a reference's, and whether it replaces the candidate tracked so
/// far. The candidate is kept unless another instance is
/// `REFERENCE_MARGIN_M` nearer. `None` when the rule does not apply (no
/// reference seen yet, no camera model, a box whose bottom is at or above
/// the horizon): the usual choice then stands.
fn by_reference<'a>(f: &FindRun, frame: &Frame, boxes: &'a [Detection]) -> Option<(&'a Detection, bool)> {
    if f.confirmed || f.reference_at.is_empty() {
        return None;
    }
    let projector = Projector::new(frame.camera.as_ref()?);
    let gaps = boxes
        .iter()
        .map(|b| {
            let at = footprint(frame, &projector, b)?;
            f.reference_at.iter().map(|a| (a - at).norm()).min_by(f64::total_cmp)
        })
        .collect::<Option<Vec<f64>>>()?;
    let best = (0..boxes.len()).min_by(|&i, &j| gaps[i].total_cmp(&gaps[j]))?;
    let Some(last) = f.last_center else { return Some((&boxes[best], false)) };
    let current = nearest_to(boxes, last)?;
    if current == best || gaps[current] - gaps[best] <= REFERENCE_MARGIN_M {
        Some((&boxes[current], false))
    } else {
        Some((&boxes[best], true))
    }
}

/// The box of an unnamed target in this frame: where a confirmed fixed
/// target projects; else the instance tracked so far; else the most confident.
fn choose_box<'a>(f: &FindRun, frame: &Frame, boxes: &'a [Detection]) -> Option<&'a Detection> {
    if f.confirmed && !f.moving {
        match f.fused.as_ref().and_then(|t| target_view(frame, t)) {
            Some(TargetView::At(u, v)) => return box_at(boxes, u, v),
            Some(TargetView::OutOfView) => return None,
            None => {}
        }
    }
    match f.last_center {
        Some(last) => nearest_to(boxes, last).map(|i| &boxes[i]),
        None => boxes.iter().max_by(|a, b| a.score.total_cmp(&b.score)),
    }
}

impl Mission {
    /// This frame's boxes of the target's class: which one is the target.
    pub(super) fn find_box(&mut self, p: &ExecutorParams, all: Vec<Detection>) -> Next {
        let places = places_of(&self.frame, &all);
        remember_landmarks(&mut self.landmarks, places.iter().copied(), self.index);
        let Some(f) = self.find() else { return self.hold() };
        let (boxes, others): (Vec<Detection>, Vec<Detection>) = all.into_iter().partition(|b| b.class_id == f.class_id);
        let reference_places: Vec<Vector2<f64>> = match f.reference {
            Some(class) if class != f.class_id => {
                places.iter().filter(|(c, _)| *c == class).map(|(_, at)| *at).collect()
            }
            _ => Vec::new(),
        };
        // The class vote: does another class's box (and none of the
        // target's) stand where the unconfirmed candidate projects?
        // A box in front of the candidate (a person walking past it) hides
        // it: that is no vote on what the candidate is.
        let rival = f.under_vote()
            && f.fused.as_ref().is_some_and(|t| {
                matches!(target_view(&self.frame, t),
                    Some(TargetView::At(u, v)) if others.iter().any(|b| centred_on(b, u, v) && !hides(&self.frame, b, t))
                        && box_at(&boxes, u, v).is_none())
            });
        let Some(f) = self.find_mut() else { return self.hold() };
        f.votes_against += u32::from(rival);
        if f.votes_against >= p.confirm_frames
            && f.votes_against >= VOTE_MARGIN * f.votes_for
            && f.votes_against >= f.votes_for + REJECT_NET
        {
            if let Some(t) = f.fused.take() {
                tracing::debug!(x = t.x, y = t.y, f.votes_for, f.votes_against, "candidate outvoted by another class");
                f.rejected.push(Vector2::new(t.x, t.y));
            }
            f.new_track();
        }
        // Where the object the target is described by stands, for
        // `by_reference` now and in later frames.
        remember_reference(f, reference_places);
        let Some(f) = self.find() else { return self.hold() };
        if boxes.is_empty() {
            return self.observed(p, None);
        }
        if !f.person.is_empty() {
            let name = f.person.clone();
            return self.call(Pending::FindIdentified { boxes: boxes.clone() }, Request::Identify { boxes, name });
        }
        if let Some((b, switch)) = by_reference(f, &self.frame, &boxes) {
            let b = b.clone();
            if switch {
                let Some(f) = self.find_mut() else { return self.hold() };
                tracing::debug!(target = %f.target, "another instance stands nearer the reference: new candidate");
                f.new_track();
            }
            return self.locate(b, String::new(), 0.0);
        }
        match choose_box(f, &self.frame, &boxes) {
            Some(b) => {
                let b = b.clone();
                self.locate(b, String::new(), 0.0)
            }
            None => self.observed(p, None),
        }
    }

    /// No instance next to its reference was found: the one set aside
    /// nearest the robot is confirmed after all and driven to.
    pub(super) fn take_set_aside(&mut self) -> Next {
        let (pose, index) = (self.frame.pose, self.index as u32);
        let Some(f) = self.find_mut() else { return self.hold() };
        let Some(s) = f.waive_reference(&pose) else { return self.hold() };
        tracing::debug!(target = ?s.fused, "no instance next to the reference: the one seen alone is the target");
        (f.confirmed, f.fused, f.goal, f.explore) = (true, Some(s.fused), Some(s.goal), Explore::Idle);
        self.emit(Event::TargetSeen {
            index,
            detection: s.detection,
            target: Some(s.fused),
            goal: Some(s.goal.pose),
            range_m: s.range_m,
            identity: String::new(),
            identity_similarity: 0.0,
        });
        self.call(Pending::FindPlanned { goal: s.goal }, self.drive(s.goal))
    }

    pub(super) fn locate(&mut self, detection: Detection, identity: String, similarity: f32) -> Next {
        let Some(f) = self.find() else { return self.hold() };
        let request = Request::Locate {
            track_key: f.track_key.clone(),
            detection: detection.clone(),
            d_s: f.d_s,
            moving: f.moving,
        };
        self.call(Pending::FindLocated { detection, identity, similarity }, request)
    }

    /// This frame's sighting (or none) updates the search, then drives,
    /// waits or explores.
    pub(super) fn observed(
        &mut self,
        p: &ExecutorParams,
        observation: Option<(Detection, String, f32, Estimate)>,
    ) -> Next {
        let (stamp, pose) = (self.frame.stamp, self.frame.pose);
        let index = self.index as u32;
        // With `size_check`: a box of a size its class cannot have at the
        // depth measured in it is a false positive (a poster on a wall
        // nearby, a person the detector gave another class): no sighting.
        let frame = &self.frame;
        let observation = observation.filter(|(b, _, _, est)| {
            let fits = !p.size_check || est.observed.or(est.fused_target).is_none_or(|t| fits_class(frame, b, &t));
            if !fits {
                tracing::debug!(class = b.class_id, at = ?est.observed, height_px = b.y_max - b.y_min, "box the wrong size for its class: no sighting");
            }
            fits
        });
        let Some(f) = self.find_mut() else { return self.hold() };
        if f.course_first.is_some_and(|c| wrap_angle(c - pose.theta).abs() <= OFF_COURSE_RAD / 2.0) {
            f.course_first = None;
        }
        // A sighting where an outvoted candidate stood is that object again;
        // one where a candidate was set aside for want of its reference is
        // that one, unless a reference has been seen next to it since.
        let observation = observation.filter(|(_, _, _, est)| {
            est.fused_target.is_none_or(|t| {
                let at = Vector2::new(t.x, t.y);
                !f.rejected.iter().any(|r| (r - at).norm() < REJECTED_M) && !f.set_aside_at(&at)
            })
        });
        // A sighting far from the candidate being voted on is another object
        // or a false positive: it does not count for this one. (False
        // positives come at random places; counted together over a long
        // look, a few of them would confirm a target where there is none.)
        let candidate = f.under_vote().then_some(f.fused).flatten();
        let observation = observation.filter(|(_, _, _, est)| match (candidate, est.fused_target) {
            (Some(c), Some(t)) => (c.xy() - t.xy()).norm() <= CONSISTENT_M,
            _ => true,
        });
        let mut seen = None;
        if f.votes_for > 0 || observation.is_some() {
            f.watched = f.watched.saturating_add(1);
        }
        match observation {
            Some((b, identity, similarity, est)) => {
                if f.votes_for == 0 && !f.confirmed {
                    tracing::debug!(at = ?est.fused_target, class = b.class_id, score = b.score, "new candidate");
                }
                f.unseen = 0;
                f.recent = (f.recent << 1 | 1) & window_mask(p.confirm_window);
                f.votes_for += 1;
                f.last_seen = Some(stamp);
                f.goal = est.goal;
                f.fused = est.fused_target.or(f.fused);
                if let Some(t) = est.fused_target {
                    f.track(stamp, t);
                }
                f.last_center = Some(b.center());
                // A fixed, unnamed target is put to the class vote over a full
                // window first; a named person (ReID decides) or a moving
                // target is confirmed by its sightings alone.
                let voted = !f.put_to_vote() || f.watched >= p.confirm_window;
                let ready = !f.confirmed
                    && voted
                    && f.recent.count_ones() >= p.confirm_frames
                    && f.votes_for >= VOTE_MARGIN * f.votes_against;
                // Only where the reference has been seen elsewhere: then the
                // target is likelier by it than here. Seen nowhere, it may
                // just be too small for the detector at this range.
                let alone = f.needs_reference()
                    && !f.reference_at.is_empty()
                    && f.fused.is_some_and(|t| !f.next_to_reference(&t.xy()));
                let behind =
                    f.put_to_vote() && !f.reference_waived && f.fused.is_some_and(|t| f.behind_route_end(&t.xy()));
                let off_course = f
                    .course_first
                    .zip(f.fused)
                    .is_some_and(|(c, t)| f.put_to_vote() && wrap_angle(bearing(pose, &t) - c).abs() > OFF_COURSE_RAD);
                if ready && off_course && !alone && !behind {
                    // "Move 8 m, then the motorcycle": the one ahead on the
                    // course, if there is one, before one off to the side.
                    tracing::debug!(course = ?f.course_first, "candidate off the course: look along the course first");
                    return self.explore(p);
                } else if ready && (alone || behind) {
                    // "The bicycle next to the stop sign", and none stood
                    // next to this one; or "move 8 m, then the motorcycle",
                    // and this one stands behind where the MOVE ended: look
                    // on for one that fits.
                    if let (Some(t), Some(goal)) = (f.fused.take(), f.goal) {
                        tracing::debug!(x = t.x, y = t.y, references = ?f.reference_at, behind, "candidate set aside");
                        let behind = behind && !alone;
                        f.set_aside.push(SetAside { fused: t, goal, detection: b, range_m: est.range_m, behind });
                        f.set_aside_since.get_or_insert(stamp);
                    }
                    f.new_track();
                } else if ready {
                    tracing::debug!(target = ?f.fused, votes_for = f.votes_for, votes_against = f.votes_against, "target confirmed");
                    f.confirmed = true;
                    f.explore = Explore::Idle;
                    seen = Some(Event::TargetSeen {
                        index,
                        detection: b,
                        target: est.fused_target,
                        goal: est.goal.map(|g| g.pose),
                        range_m: est.range_m,
                        identity,
                        identity_similarity: similarity,
                    });
                }
            }
            None => {
                f.recent = (f.recent << 1) & window_mask(p.confirm_window);
                f.unseen += 1;
                if f.under_vote() && f.recent == 0 {
                    // Not seen again for a whole window: forget the
                    // candidate, keeping where it was (`fused`) as a lead
                    // for the search.
                    tracing::debug!(lead = ?f.fused, votes_for = f.votes_for, votes_against = f.votes_against, "candidate not seen again: forgotten, kept as a lead");
                    f.new_track();
                }
                if f.moving && f.confirmed && f.last_seen.is_some_and(|t| stamp - t > p.follow_lost_s) {
                    f.confirmed = false;
                }
            }
        }
        let (confirmed, goal, moving, waiting) =
            (f.confirmed, f.goal, f.moving, f.recent != 0 || f.unseen < p.unseen_frames);
        if let Some(event) = seen {
            self.emit(event);
        }
        if confirmed {
            let Some(goal) = goal else { return self.hold() };
            if moving {
                return self.follow(stamp, goal);
            }
            return self.call(Pending::FindPlanned { goal }, self.drive(goal));
        }
        if waiting {
            // A candidate to confirm, or still looking from here: hold still.
            return self.hold();
        }
        self.explore(p)
    }
}

/// The bits of the last `window` frames (1 to 64).
fn window_mask(window: u32) -> u64 {
    match window.clamp(1, 64) {
        64 => u64::MAX,
        w => (1u64 << w) - 1,
    }
}

#[cfg(test)]
#[path = "find_tests.rs"]
mod tests;
