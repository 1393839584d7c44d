//! Frontier: where the space the depth has seen free meets space it has
//! not seen (docs/design.md §4, "Frontier"). Off unless
//! `FollowParams::frontier` (`--local-planner-frontier`) is set.
//!
//! A FIND whose target is not in view looks around, then drives search
//! legs along the route's course. A target hidden behind pillars,
//! furniture or a door frame is in the space the camera has not looked at
//! from where it stood, which legs along the course may never see
//! (docs/evaluation.md, "Generated worlds"). The seen
//! grid ([`SeenGrid`], `SEEN_M` cells in `odom`) keeps, for the last
//! `SEEN_KEEP_S` within `SEEN_RANGE_M` of the robot, which cells a frame's
//! depth passed through (free) and where a blocking point ended a bearing
//! (blocked); each frame's rays ([`crate::cloud::SeenRange::rays`]) mark
//! them, the newest look winning. It moves with the odometry when that is
//! re-anchored at a reached subgoal, like the detour grid, so it is no
//! global map.
//!
//! The frontier ([`SeenGrid::frontier`]) is the nearest place, along seen
//! free cells with no blocked cell beside them, where a free cell borders
//! one never seen: the shadow behind an occluder, a door's opening, the end
//! of what the depth reached. Edges shorter than `FRONTIER_MIN_CELLS` cells
//! (a chair leg's shadow) and those within `FRONTIER_MIN_M` of the robot
//! (the floor beside and under the body, which the camera never sees) do
//! not count. Each frame reports the nearest edges; once the search legs
//! are spent, the executor drives on toward the nearest ahead
//! (`gateway/src/executor/machine/explore.rs`).

use std::collections::{BTreeMap, VecDeque};

use nalgebra::Vector2;
use vlnav_geometry::Pose2;

use crate::cloud::SeenRange;

/// Side of a seen cell, m.
const SEEN_M: f64 = 0.25;
/// How long a seen cell is kept without being seen again, s.
const SEEN_KEEP_S: f64 = 300.0;
/// Seen cells farther than this from the robot are dropped, m.
const SEEN_RANGE_M: f64 = 20.0;
/// Frontier cells nearer the robot than this do not count, m.
const FRONTIER_MIN_M: f64 = 1.5;
/// An edge of unseen space shorter than this many cells does not count.
const FRONTIER_MIN_CELLS: usize = 4;
/// Cells this near the robot may be crossed unseen (the body stands on them), m.
const OWN_GROUND_M: f64 = 0.75;
/// The frontier is searched again after this much sensor time, s.
const REFRESH_S: f64 = 0.5;
/// At most this many edges are reported, nearest first.
const FRONTIER_MAX: usize = 8;

/// What a frame saw of one cell.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Seen {
    blocked: bool,
    stamp: f64,
}

/// The rolling grid of seen cells, `odom`, and the last frontier found.
#[derive(Clone, Debug, Default)]
pub(super) struct SeenGrid {
    cells: BTreeMap<(i32, i32), Seen>,
    frontier: Vec<Vector2<f64>>,
    searched: Option<f64>,
}

fn key(at: &Vector2<f64>) -> (i32, i32) {
    super::cell_of(at, SEEN_M)
}

fn centre(k: (i32, i32)) -> Vector2<f64> {
    Vector2::new((f64::from(k.0) + 0.5) * SEEN_M, (f64::from(k.1) + 0.5) * SEEN_M)
}

const FOUR: [(i32, i32); 4] = [(1, 0), (-1, 0), (0, 1), (0, -1)];
const EIGHT: [(i32, i32); 8] = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)];

impl SeenGrid {
    /// Marks what a frame taken at `pose` (`odom`) at `stamp` saw: every
    /// cell along each measured bearing up to where it saw free, free; the
    /// cell of a blocking point that ended a bearing, blocked (a blocked
    /// cell marked by this frame stays blocked). Drops cells too old or too far.
    pub(super) fn observe(&mut self, pose: &Pose2, seen: &SeenRange, stamp: f64) {
        let here = pose.position();
        self.cells.retain(|k, c| stamp - c.stamp <= SEEN_KEEP_S && (centre(*k) - here).norm() <= SEEN_RANGE_M);
        let origin = pose.transform(&seen.origin());
        let mut ends = Vec::new();
        for (bearing, free, blocked) in seen.rays() {
            let (s, c) = (pose.theta + bearing).sin_cos();
            let dir = Vector2::new(c, s);
            let steps = (free / (0.5 * SEEN_M)).floor() as usize;
            let mut last = None;
            for i in 0..=steps {
                let k = key(&(origin + dir * (i as f64 * 0.5 * SEEN_M)));
                // Two steps a cell: each cell once.
                if last.replace(k) == Some(k) {
                    continue;
                }
                let cell = self.cells.entry(k).or_insert(Seen { blocked: false, stamp });
                if !(cell.blocked && cell.stamp == stamp) {
                    *cell = Seen { blocked: false, stamp };
                }
            }
            if let Some(b) = blocked {
                ends.push(key(&(origin + dir * b)));
            }
        }
        for k in ends {
            self.cells.insert(k, Seen { blocked: true, stamp });
        }
    }

    /// Moves every cell with the odometry re-anchored (`last` → `now`).
    pub(super) fn reanchor(&mut self, last: Pose2, now: Pose2) {
        let old = std::mem::take(&mut self.cells);
        for (k, c) in old {
            let at = now.transform(&last.inverse_transform(&centre(k)));
            self.cells.insert(key(&at), c);
        }
        self.frontier.clear();
        self.searched = None;
    }

    pub(super) fn clear(&mut self) {
        *self = Self::default();
    }

    /// The frontier seen from `here` (`odom`) at `stamp`, searched again
    /// once `REFRESH_S` has passed since the last search.
    pub(super) fn frontier_at(&mut self, here: &Vector2<f64>, stamp: f64) -> &[Vector2<f64>] {
        if self.searched.is_none_or(|t| stamp < t || stamp - t >= REFRESH_S) {
            self.frontier = self.frontier(here);
            self.searched = Some(stamp);
        }
        &self.frontier
    }

    /// The frontier from `here` (`odom`), along passable cells: of each
    /// edge of unseen space at least `FRONTIER_MIN_CELLS` long and
    /// `FRONTIER_MIN_M` away, its nearest cell; nearest first, at most
    /// `FRONTIER_MAX`. Searched on a dense window round the robot
    /// ([`Window`]), which holds every cell the search reaches.
    pub(super) fn frontier(&self, here: &Vector2<f64>) -> Vec<Vector2<f64>> {
        let w = Window::new(&self.cells, key(here));
        let start = w.start;
        let mut order = Vec::new();
        let mut visited = vec![false; w.state.len()];
        let mut queue = VecDeque::from([start]);
        visited[w.index(start)] = true;
        while let Some(k) = queue.pop_front() {
            order.push(k);
            for (di, dj) in FOUR {
                let n = (k.0 + di, k.1 + dj);
                if (n.0 - start.0).abs() > SEARCH_CELLS || (n.1 - start.1).abs() > SEARCH_CELLS {
                    continue;
                }
                let i = w.index(n);
                if !visited[i] && w.passable(n, here) {
                    visited[i] = true;
                    queue.push_back(n);
                }
            }
        }
        // An unseen cell counts when at most two of its four sides were
        // seen: a hole between the rays of a look is not unseen space.
        let unseen = |n: (i32, i32)| {
            w.at(n) == UNSEEN && FOUR.iter().filter(|(di, dj)| w.at((n.0 + di, n.1 + dj)) != UNSEEN).count() <= 2
        };
        let is_edge = |k: (i32, i32)| {
            w.at(k) == FREE
                && (centre(k) - here).norm() >= FRONTIER_MIN_M
                && FOUR.iter().any(|(di, dj)| unseen((k.0 + di, k.1 + dj)))
        };
        let mut edge = vec![false; w.state.len()];
        for &k in &order {
            edge[w.index(k)] = is_edge(k);
        }
        // Cells in the order the search reached them, nearest first: each
        // edge is found from its nearest cell.
        let mut taken = vec![false; w.state.len()];
        let mut found = Vec::new();
        for &k in &order {
            if !edge[w.index(k)] || taken[w.index(k)] {
                continue;
            }
            let mut size = 0;
            let mut stack = vec![k];
            taken[w.index(k)] = true;
            while let Some(c) = stack.pop() {
                size += 1;
                for (di, dj) in EIGHT {
                    let n = (c.0 + di, c.1 + dj);
                    if w.contains(n) && edge[w.index(n)] && !taken[w.index(n)] {
                        taken[w.index(n)] = true;
                        stack.push(n);
                    }
                }
            }
            if size >= FRONTIER_MIN_CELLS {
                found.push(centre(k));
                if found.len() == FRONTIER_MAX {
                    break;
                }
            }
        }
        found
    }
}

/// The search reaches at most this many cells from the robot along either axis.
const SEARCH_CELLS: i32 = (SEEN_RANGE_M / SEEN_M) as i32;
/// The window reaches this many cells farther than the search, for the
/// neighbours its tests look at.
const WINDOW_MARGIN: i32 = 3;
const UNSEEN: u8 = 0;
const FREE: u8 = 1;
const BLOCKED: u8 = 2;

/// The seen grid round `start` as a dense square: `UNSEEN`, `FREE` or
/// `BLOCKED` per cell, outside it unseen.
struct Window {
    start: (i32, i32),
    half: i32,
    side: usize,
    state: Vec<u8>,
}

impl Window {
    fn new(cells: &BTreeMap<(i32, i32), Seen>, start: (i32, i32)) -> Self {
        let half = SEARCH_CELLS + WINDOW_MARGIN;
        let side = (2 * half + 1) as usize;
        let mut w = Self { start, half, side, state: vec![UNSEEN; side * side] };
        let (lo, hi) = ((start.0 - half, start.1 - half), (start.0 + half, start.1 + half));
        for (&k, c) in cells.range(lo..=(hi.0, i32::MAX)) {
            if k.1 >= lo.1 && k.1 <= hi.1 {
                let i = w.index(k);
                w.state[i] = if c.blocked { BLOCKED } else { FREE };
            }
        }
        w
    }

    fn contains(&self, k: (i32, i32)) -> bool {
        (k.0 - self.start.0).abs() <= self.half && (k.1 - self.start.1).abs() <= self.half
    }

    /// The index of `k`, which must be within the window.
    fn index(&self, k: (i32, i32)) -> usize {
        (k.1 - self.start.1 + self.half) as usize * self.side + (k.0 - self.start.0 + self.half) as usize
    }

    fn at(&self, k: (i32, i32)) -> u8 {
        if self.contains(k) { self.state[self.index(k)] } else { UNSEEN }
    }

    /// Whether the robot's centre may pass cell `k`: seen free with no
    /// blocked cell among its eight neighbours, or (seen or not) within
    /// `OWN_GROUND_M` of `here`.
    fn passable(&self, k: (i32, i32), here: &Vector2<f64>) -> bool {
        if (centre(k) - here).norm() <= OWN_GROUND_M {
            return self.at(k) != BLOCKED;
        }
        self.at(k) == FREE && EIGHT.iter().all(|(di, dj)| self.at((k.0 + di, k.1 + dj)) != BLOCKED)
    }
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use nalgebra::Vector2;
    use vlnav_geometry::Pose2;

    use super::super::test_support::{planner, turn_in_place_to};
    use super::super::{FollowParams, RobotState};
    use super::SeenGrid;
    use crate::cloud::{ObstacleCloud, SeenRange};

    /// What a camera at the origin sees all round (one ray every 0.5°) in
    /// a square room of half-side `half` m with a round pillar of radius
    /// 0.3 m at `pillar`, the room's wall open between `door` (y from, to)
    /// on the +x side, where the depth reaches 2 m farther.
    fn look(half: f64, pillar: Option<Vector2<f64>>, door: Option<(f64, f64)>) -> SeenRange {
        let mut s = SeenRange::new(Vector2::zeros());
        for i in 0..720 {
            let b = -PI + (f64::from(i) + 0.5) * PI / 360.0;
            let dir = Vector2::new(b.cos(), b.sin());
            // The wall: where the ray leaves the square.
            let mut wall = half / dir.x.abs().max(dir.y.abs());
            let at = dir * wall;
            let through =
                door.is_some_and(|(lo, hi)| at.x > 0.0 && (at.x - half).abs() < 1e-6 && at.y > lo && at.y < hi);
            if through {
                wall += 2.0;
            }
            let mut hit = if through { None } else { Some(wall) };
            let mut reach = wall;
            if let Some(c) = pillar {
                // Ray–circle: the nearer root of |t·dir − c| = 0.3.
                let b2 = dir.dot(&c);
                let disc = b2 * b2 - c.norm_squared() + 0.09;
                if disc >= 0.0 && b2 - disc.sqrt() > 0.0 && b2 - disc.sqrt() < reach {
                    reach = b2 - disc.sqrt();
                    hit = Some(reach);
                }
            }
            let p = dir * reach;
            match hit {
                Some(_) => s.record_obstacle(p.x, p.y),
                None => s.record(p.x, p.y),
            }
        }
        s
    }

    #[test]
    fn a_room_seen_all_round_has_no_frontier() {
        let mut g = SeenGrid::default();
        g.observe(&Pose2::new(0.0, 0.0, 0.0), &look(4.0, None, None), 0.0);
        assert!(g.frontier(&Vector2::zeros()).is_empty());
    }

    #[test]
    fn the_frontier_is_the_shadow_behind_a_pillar() {
        let mut g = SeenGrid::default();
        g.observe(&Pose2::new(0.0, 0.0, 0.0), &look(5.0, Some(Vector2::new(2.0, 0.0)), None), 0.0);
        let f = g.frontier(&Vector2::zeros()).first().copied().expect("the pillar's shadow");
        // Beside or behind the pillar, not at the walls.
        assert!(f.x > 1.5 && f.x < 4.5 && f.y.abs() < 1.0, "{f:?}");
    }

    #[test]
    fn the_frontier_is_the_door_of_a_room_seen_all_round() {
        let mut g = SeenGrid::default();
        g.observe(&Pose2::new(0.0, 0.0, 0.0), &look(3.0, None, Some((-0.6, 0.6))), 0.0);
        let f = g.frontier(&Vector2::zeros()).first().copied().expect("through the door");
        assert!(f.x > 2.5 && f.y.abs() < 1.5, "{f:?}");
    }

    #[test]
    fn the_grid_moves_with_reanchored_odometry() {
        let mut g = SeenGrid::default();
        g.observe(&Pose2::new(0.0, 0.0, 0.0), &look(3.0, None, Some((-0.6, 0.6))), 0.0);
        g.reanchor(Pose2::new(0.0, 0.0, 0.0), Pose2::new(10.0, 0.0, PI / 2.0));
        let f = g.frontier(&Vector2::new(10.0, 0.0)).first().copied().expect("through the door");
        // The door that was along +x is now along +y of the new frame.
        assert!(f.y > 2.5 && (f.x - 10.0).abs() < 1.5, "{f:?}");
    }

    #[test]
    fn a_step_reports_the_frontier_in_odom_only_when_asked_to() {
        // The robot at (10, 5) facing +y turns in place; its frame sees a
        // pillar 2 m ahead: the shadow lies about (10, 7.5) in `odom`.
        let cloud = ObstacleCloud { seen: Some(look(5.0, Some(Vector2::new(2.0, 0.0)), None)), ..Default::default() };
        let mut input = turn_in_place_to(PI / 2.0, &cloud);
        input.pose = Pose2::new(10.0, 5.0, PI / 2.0);
        input.goal.pose = input.pose;
        let on = FollowParams { frontier: true, ..FollowParams::default() };
        let out = RobotState::default().step(planner(), &on, input.clone());
        let f = out.frontier.first().copied().expect("the pillar's shadow");
        assert!((f.x - 10.0).abs() < 1.0 && f.y > 6.5 && f.y < 9.5, "{f:?}");
        let off = RobotState::default().step(planner(), &FollowParams::default(), input);
        assert!(off.frontier.is_empty());
    }
}
