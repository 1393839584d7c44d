//! The bounded exploration of a FIND whose target is not in view: a
//! revisit of where an earlier step saw its class, look-arounds of scan
//! turns, search legs, then a question to the user.

use nalgebra::Vector3;
use vlnav_geometry::wrap_angle as wrap;

use super::{FindRun, Mission, MoveQuery, Next, OFF_COURSE_RAD, Pending, Request, bearing};
use crate::config::ExecutorParams;
use crate::executor::model::*;

/// A search leg toward a lead closer than this (beyond the stopping
/// distance) goes straight ahead instead, m.
const LEAD_MIN_M: f64 = 0.5;

/// Legs toward frontiers after the search legs are spent, at most.
const FRONTIER_LEGS: u32 = 2;
/// A search leg toward a frontier goes at most this far, m.
const FRONTIER_LEG_MAX_M: f64 = 8.0;
/// A search leg stops this much short of the frontier it drives to (the
/// edge's cell lies beside what casts its shadow; from there the camera
/// already sees into it), m.
const FRONTIER_SHORT_M: f64 = 0.75;
/// Frontiers farther off the search's heading than this are not searched, rad.
const FRONTIER_AHEAD_RAD: f64 = std::f64::consts::FRAC_PI_2;
/// What turning off the search's heading costs a frontier, m per quarter turn.
const FRONTIER_TURN_COST_M: f64 = 4.0;

/// Sensor seconds one scan turn of exploration may take before looking anyway.
const SCAN_TURN_LIMIT_S: f64 = 4.0;
/// A search leg slower than this on average ends early, m/s.
const SEARCH_MIN_SPEED: f64 = 0.2;

/// The next phase of a fruitless search, given where the last one ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum ExplorePlan {
    /// Turn once more (the scan turn number, 0-based) within the current look-around.
    Turn(u32),
    /// Drive one search leg (1-based leg number).
    Search(u32),
    /// Exploration is exhausted: ask the user.
    Ask,
}

/// One search leg from `pose`: toward `lead` — where a sighting not yet
/// confirmed put the target — to look again from closer (a detector finds a
/// small, distant object in only a few frames; docs/perception.md), else
/// straight ahead. Toward a lead it goes half the way to the stopping
/// distance, at least `search_leg_m`, never past that distance; a lead
/// already within reach is not worth another look from the same place.
pub(crate) fn search_leg(pose: Pose2, lead: Option<&Vector3<f64>>, d_s: f64, p: &ExecutorParams) -> MoveQuery {
    let ahead = MoveQuery { anchor: pose, f_dist: p.search_leg_m, yaw: 0.0, d_s: 0.0 };
    let Some(t) = lead else { return ahead };
    let room = (t.x - pose.x).hypot(t.y - pose.y) - d_s;
    if room < LEAD_MIN_M {
        return ahead;
    }
    let f_dist = (room / 2.0).max(p.search_leg_m).min(room);
    MoveQuery { anchor: pose, f_dist, yaw: wrap(bearing(pose, t) - pose.theta), d_s: 0.0 }
}

/// One search leg from `pose` with no lead, toward one of `frontier`
/// (`odom`, the nearest edges of what the depth has not seen, from the
/// local planner; `control/frontier.rs` there): a target hidden behind
/// pillars, furniture or a door frame is in the space the robot has not
/// looked at. The search's heading (`pose.theta`, the route's course) still
/// says where the target most likely is, so of the edges within
/// `FRONTIER_AHEAD_RAD` of it the one nearest counting `FRONTIER_TURN_COST_M`
/// per quarter turn off it; toward it, facing it, up to `FRONTIER_SHORT_M`
/// short of it and at most `FRONTIER_LEG_MAX_M`. `None` where no edge is
/// ahead, or the one chosen is nearer than the least lead worth driving
/// (`LEAD_MIN_M`).
pub(crate) fn frontier_leg(pose: Pose2, frontier: &[[f64; 2]]) -> Option<MoveQuery> {
    let off = |[x, y]: &[f64; 2]| wrap((y - pose.y).atan2(x - pose.x) - pose.theta).abs();
    let cost = |e: &[f64; 2]| (e[0] - pose.x).hypot(e[1] - pose.y) + FRONTIER_TURN_COST_M * off(e) / FRONTIER_AHEAD_RAD;
    let [x, y] = frontier.iter().filter(|e| off(e) <= FRONTIER_AHEAD_RAD).min_by(|a, b| cost(a).total_cmp(&cost(b)))?;
    let room = (x - pose.x).hypot(y - pose.y) - FRONTIER_SHORT_M;
    if room < LEAD_MIN_M {
        return None;
    }
    let heading = (y - pose.y).atan2(x - pose.x);
    Some(MoveQuery {
        anchor: Pose2::new(pose.x, pose.y, heading),
        f_dist: room.min(FRONTIER_LEG_MAX_M),
        yaw: 0.0,
        d_s: 0.0,
    })
}

/// Bounded exploration schedule: a look-around of `scan_turns` turns, then
/// a search leg, up to `search_legs` legs, each followed by a fan of
/// `2 · search_fan_turns` turns about the way ahead.
pub(crate) fn after_look(turn: u32, leg: u32, p: &ExecutorParams) -> ExplorePlan {
    if turn + 1 < turns_of_look(leg, p) {
        ExplorePlan::Turn(turn + 1)
    } else if leg < p.search_legs {
        ExplorePlan::Search(leg + 1)
    } else {
        ExplorePlan::Ask
    }
}

/// Turns of the look after `leg` search legs: all around before the first
/// leg; after a leg, the fan about the way ahead.
fn turns_of_look(leg: u32, p: &ExecutorParams) -> u32 {
    if leg == 0 { p.scan_turns } else { 2 * p.search_fan_turns }
}

/// Heading of turn `turn` (0-based) of the look after `leg` search legs,
/// off the look's origin, rad: `turn + 1` scan turns on round all about;
/// in a fan, `+1 … +n` scan turns, then `−1 … −n`.
pub(crate) fn look_yaw(turn: u32, leg: u32, p: &ExecutorParams) -> f64 {
    let n = p.search_fan_turns;
    let k = if leg == 0 || turn < n { f64::from(turn + 1) } else { -f64::from(turn - n + 1) };
    wrap(p.scan_turn_rad * k)
}

#[derive(Clone, Copy, Debug)]
pub(super) enum Explore {
    Idle,
    /// `since`: the stamp the turn or leg began.
    /// `origin`: the pose the look-around began at; its turns are counted
    /// from it, so each turn's tolerance does not shrink the look-around.
    Turn {
        goal: Goal,
        turn: u32,
        leg: u32,
        since: f64,
        origin: Pose2,
    },
    Look {
        frames_left: u32,
        turn: u32,
        leg: u32,
        origin: Pose2,
    },
    /// `length`: the leg's length, m (what its time limit allows for).
    Search {
        goal: Goal,
        leg: u32,
        since: f64,
        length: f64,
    },
}

#[derive(Clone, Copy, Debug)]
pub(super) enum ExploreGoalFor {
    /// The first turn of a look-around from `origin` after `leg` search legs;
    /// `announce`: report the exploration's start when the goal is known.
    Scan { leg: u32, origin: Pose2, announce: bool },
    /// Turn `turn` of the look-around that began at `origin`.
    NextTurn { turn: u32, leg: u32, origin: Pose2 },
    /// Search leg number `leg`, `length` m long.
    SearchLeg { leg: u32, length: f64 },
    /// The leg toward where an earlier step saw the target's class; its
    /// time limit allows for `length` m.
    Revisit { length: f64 },
}

impl Mission {
    /// Scan turn `turn` (0-based) of the look after `leg` search legs that
    /// began at `origin`.
    fn turn_query(p: &ExecutorParams, origin: Pose2, leg: u32, turn: u32) -> MoveQuery {
        MoveQuery { anchor: origin, f_dist: 0.0, yaw: look_yaw(turn, leg, p), d_s: 0.0 }
    }

    /// Where a search leg sets off from: the robot's position, facing the
    /// search's heading (else the look's origin).
    fn search_from(f: &FindRun, pose: Pose2, origin: Pose2) -> Pose2 {
        Pose2::new(pose.x, pose.y, f.search_heading.unwrap_or(origin.theta))
    }

    /// The target is not in view and nothing is to be confirmed: the next
    /// move of the bounded exploration.
    pub(super) fn explore(&mut self, p: &ExecutorParams) -> Next {
        let (pose, stamp) = (self.frame.pose, self.frame.stamp);
        let index = self.index as u32;
        let course = self.course;
        let Some(f) = self.find_mut() else { return self.hold() };
        let state = std::mem::replace(&mut f.explore, Explore::Idle);
        match state {
            Explore::Idle if f.revisit.is_some() => {
                // An earlier step saw one where it is not seen from here (the
                // landmark just reached may hide it): look again from closer
                // before looking around. A place already within reach is
                // looked for by the look-around instead.
                let lead = f.revisit.take().map(|at| Vector3::new(at.x, at.y, 0.0));
                let room = lead.as_ref().map_or(0.0, |t| (t.x - pose.x).hypot(t.y - pose.y) - f.d_s);
                f.explore = Explore::Idle;
                if room < LEAD_MIN_M {
                    return self.explore(p);
                }
                let query = search_leg(pose, lead.as_ref(), f.d_s, p);
                tracing::debug!(
                    ?lead,
                    f_dist = query.f_dist,
                    yaw = query.yaw,
                    "revisit leg toward a landmark an earlier step saw"
                );
                let what = ExploreGoalFor::Revisit { length: p.search_leg_m };
                self.call(Pending::ExploreGoal(what), Request::MoveGoal(query))
            }
            Explore::Idle => {
                // Look first where the target was last seen (a person who
                // walked out of view went that way); else, where the robot
                // faces more than a scan turn off the route's course, along
                // the course (a MOVE that went round a cable's end ended
                // facing 73° off it, and the look-around, turning on from
                // there, came to the chair off the route before the one on
                // it: evaluation, lab); then on round from there.
                // The search's heading is that first way looked (the course,
                // or toward the last sighting); the look-around's origin is
                // one scan turn short of it, so that its first turn faces it.
                let first = match (f.predicted(stamp), course) {
                    // An instance seen off the course waits for the look along it.
                    (_, Some(c)) if f.course_first.is_some() => Some(c),
                    (Some(t), _) => Some(bearing(pose, &t)),
                    (None, Some(c)) if wrap(c - pose.theta).abs() > OFF_COURSE_RAD => Some(c),
                    (None, _) => None,
                };
                let origin = first.map_or(pose, |h| Pose2::new(pose.x, pose.y, wrap(h - p.scan_turn_rad)));
                f.search_heading.get_or_insert(first.unwrap_or(pose.theta));
                let what = ExploreGoalFor::Scan { leg: 0, origin, announce: true };
                self.call(Pending::ExploreGoal(what), Request::MoveGoal(Self::turn_query(p, origin, 0, 0)))
            }
            Explore::Turn { goal, .. } | Explore::Search { goal, .. } => {
                self.call(Pending::ExploreDriven(state), self.drive(goal))
            }
            Explore::Look { frames_left, turn, leg, origin } if frames_left > 1 => {
                f.explore = Explore::Look { frames_left: frames_left - 1, turn, leg, origin };
                self.hold()
            }
            // Looked around, and on, for long enough (or the exploration is
            // exhausted, below): the instance seen without its reference is
            // the target after all.
            Explore::Look { .. } if f.reference_search_over(stamp) => self.take_set_aside(),
            Explore::Look { turn, leg, origin, .. } => {
                let plan = after_look(turn, leg, p);
                let onward = if plan == ExplorePlan::Ask && f.fused.is_none() && leg < p.search_legs + FRONTIER_LEGS {
                    frontier_leg(Self::search_from(f, pose, origin), &f.frontier)
                } else {
                    None
                };
                match (plan, onward) {
                    // The search legs are spent and nothing led anywhere: on to
                    // where the robot has not looked, while the local planner
                    // reports such a place ahead.
                    (_, Some(query)) => {
                        let l = leg + 1;
                        f.search_heading = Some(query.anchor.theta);
                        tracing::debug!(leg = l, frontier = ?f.frontier, f_dist = query.f_dist, heading = query.anchor.theta, "frontier leg");
                        let what = ExploreGoalFor::SearchLeg { leg: l, length: query.f_dist.max(p.search_leg_m) };
                        self.call(Pending::ExploreGoal(what), Request::MoveGoal(query))
                    }
                    (ExplorePlan::Turn(t), _) => {
                        let what = ExploreGoalFor::NextTurn { turn: t, leg, origin };
                        self.call(Pending::ExploreGoal(what), Request::MoveGoal(Self::turn_query(p, origin, leg, t)))
                    }
                    (ExplorePlan::Search(l), _) => {
                        // Along the search's heading: a fan ends facing off
                        // it, and a leg toward a lead, or round something,
                        // ends facing elsewhere.
                        // A lead behind where the route's MOVE ended is not
                        // the one the instruction means (find.rs, `route_end`).
                        let lead = f.fused.filter(|t| !f.behind_route_end(&t.xy()));
                        let query = search_leg(Self::search_from(f, pose, origin), lead.as_ref(), f.d_s, p);
                        tracing::debug!(leg = l, ?lead, f_dist = query.f_dist, yaw = query.yaw, "search leg");
                        let what = ExploreGoalFor::SearchLeg { leg: l, length: p.search_leg_m };
                        self.call(Pending::ExploreGoal(what), Request::MoveGoal(query))
                    }
                    (ExplorePlan::Ask, _) if f.can_waive() => self.take_set_aside(),
                    (ExplorePlan::Ask, None) => {
                        let who = if f.person.is_empty() {
                            format!("the {}", f.target)
                        } else {
                            format!("{} ({})", f.person, f.target)
                        };
                        self.ask(
                            format!(
                                "step {}: {who} not found after looking all around and {leg} search leg(s)",
                                index + 1
                            ),
                            format!("I could not find {who}. Where should I look, or should I skip it?"),
                        );
                        self.hold()
                    }
                }
            }
        }
    }

    pub(super) fn explore_goal(&mut self, what: ExploreGoalFor, goal: Goal) -> Next {
        let stamp = self.frame.stamp;
        let index = self.index as u32;
        let next = match what {
            ExploreGoalFor::Scan { leg, origin, announce } => {
                if announce {
                    self.emit(Event::Exploring { index, phase: ExplorePhase::Scan, attempt: 1 });
                }
                Explore::Turn { goal, turn: 0, leg, since: stamp, origin }
            }
            ExploreGoalFor::NextTurn { turn, leg, origin } => Explore::Turn { goal, turn, leg, since: stamp, origin },
            ExploreGoalFor::SearchLeg { leg, length } => {
                self.emit(Event::Exploring { index, phase: ExplorePhase::Search, attempt: leg });
                Explore::Search { goal, leg, since: stamp, length }
            }
            // Counted as leg 0: the look-around and the search legs follow as usual.
            ExploreGoalFor::Revisit { length } => {
                self.emit(Event::Exploring { index, phase: ExplorePhase::Revisit, attempt: 1 });
                Explore::Search { goal, leg: 0, since: stamp, length }
            }
        };
        if let Some(f) = self.find_mut() {
            f.explore = next;
        }
        self.hold()
    }

    pub(super) fn explore_driven(&mut self, p: &ExecutorParams, state: Explore, answer: DriveAnswer) -> Next {
        let (stamp, pose) = (self.frame.stamp, self.frame.pose);
        let index = self.index as u32;
        if let (false, Some(f)) = (answer.frontier.is_empty(), self.find_mut()) {
            f.frontier.clone_from(&answer.frontier);
        }
        let (next, twist) = match state {
            Explore::Turn { goal, turn, leg, since, origin } => {
                // A scan turn that does not finish in time (a wheel stalled
                // short of the heading), or that the local planner reports
                // BLOCKED (no room to turn), looks from where it got to: a
                // robot wedged beside a cable waited out every turn of two
                // look-arounds and the mission ran out of time unasked.
                let done = matches!(answer.status, DriveStatus::Reached | DriveStatus::Blocked);
                if done || stamp - since >= SCAN_TURN_LIMIT_S {
                    (Explore::Look { frames_left: p.look_frames, turn, leg, origin }, Twist::ZERO)
                } else {
                    (Explore::Turn { goal, turn, leg, since, origin }, answer.cmd)
                }
            }
            Explore::Search { goal, leg, since, length } => {
                let overdue = stamp - since >= length / SEARCH_MIN_SPEED + SCAN_TURN_LIMIT_S;
                let ended =
                    matches!(answer.status, DriveStatus::Reached | DriveStatus::Blocked | DriveStatus::NoProgress);
                if overdue || ended {
                    self.emit(Event::Exploring { index, phase: ExplorePhase::Scan, attempt: leg + 1 });
                    let what = ExploreGoalFor::Scan { leg, origin: pose, announce: false };
                    return self.call(Pending::ExploreGoal(what), Request::MoveGoal(Self::turn_query(p, pose, leg, 0)));
                }
                (Explore::Search { goal, leg, since, length }, answer.cmd)
            }
            other => (other, Twist::ZERO),
        };
        if let Some(f) = self.find_mut() {
            f.explore = next;
        }
        self.done(twist, None)
    }
}

#[cfg(test)]
#[path = "explore_tests.rs"]
mod tests;
