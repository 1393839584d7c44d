//! Detour layer: a plan beyond the 343 paths' 3 m, made only when the
//! direct way makes no progress (docs/design.md §4, "Detours"). Off unless
//! `FollowParams::detour` (`--local-planner-detour`) is set.
//!
//! The paths and their cost see the cloud within 4.25 m; a restricted patch
//! wider than that across a MOVE leg, or a corridor narrowed by a hazard,
//! leaves every path toward the goal blocked, and the goal-heading term
//! turns the robot back toward the blocked line at each edge it reaches.
//! The detour layer keeps what the obstacle memory knew a little longer and
//! farther: a rolling grid ([`DetourGrid`], 0.1 m cells in `odom`) of the
//! keep-out cells (obstacles, no-go markings; never moving cells or people)
//! of the last `GRID_KEEP_S` within `GRID_RANGE_M` of the robot. A grid
//! cell is forgotten where a frame looks at its place and its depth reaches
//! past it, as the memory's cells are; it moves with the odometry when that
//! is re-anchored at a reached subgoal, so nothing here is a global map.
//!
//! When the progress watchdog fires, or no path is free, or a turn toward
//! the goal is BLOCKED, the grid is searched (A*, 8-connected, over a
//! window round the robot and the goal; unknown counts as free) for a way
//! that keeps the robot's centre `half_width_m + guard_margin_m` from every
//! keep-out cell, at a cost that rises within the sweep disc's radius, so
//! the way leaves room to turn on the spot. Where it finds one, the robot
//! drives to the farthest point of it within the paths' reach that it can
//! see in a straight line (the waypoint), replans from there, and drops
//! the detour once the straight line to the goal is clear. While detouring,
//! the distance it reports is the way's length, so the executor's progress
//! check measures progress along the way. Where the grid shows no way, the
//! step reports what it did before, and the executor asks.

use std::collections::{BTreeMap, BinaryHeap};

use nalgebra::Vector2;

use super::{FollowParams, RobotState, StepInput};
use crate::cloud::Cell;

/// Side of a detour grid cell, m.
pub(super) const GRID_M: f64 = 0.1;
/// How long a grid cell is kept without being seen again, s.
pub(super) const GRID_KEEP_S: f64 = 300.0;
/// Grid cells farther than this from the robot are dropped, m.
pub(super) const GRID_RANGE_M: f64 = 25.0;
/// The search window: robot and goal, this much round them, m.
const SEARCH_MARGIN_M: f64 = 5.0;
/// A goal farther than this is searched toward along its line only, m.
const SEARCH_REACH_M: f64 = 15.0;
/// A waypoint lies no farther along the way than the paths reach, m.
pub(super) const WAYPOINT_REACH_M: f64 = 3.0;
/// A waypoint is passed once the robot is this near it, m.
const WAYPOINT_PASSED_M: f64 = 0.5;
/// The way is searched again this often while detouring, s of sensor time.
const REPLAN_S: f64 = 2.0;
/// A detour's way may be at most this many times the straight distance to
/// the goal, plus `DETOUR_SLACK_M`.
const DETOUR_STRETCH: f64 = 1.5;
const DETOUR_SLACK_M: f64 = 3.0;
/// Cost per metre added at a cell at the lethal clearance, falling to 0 at
/// the sweep disc's radius.
const NEAR_COST: f64 = 4.0;

/// One remembered keep-out cell of the grid.
#[derive(Clone, Copy, Debug)]
pub(super) struct GridCell {
    pub(super) at: Vector2<f64>,
    pub(super) cell: Cell,
    pub(super) stamp: f64,
}

/// The rolling grid of keep-out cells, `odom`, one per `GRID_M` cell.
#[derive(Clone, Debug, Default)]
pub(super) struct DetourGrid {
    pub(super) cells: BTreeMap<(i32, i32), GridCell>,
}

pub(super) fn grid_key(at: &Vector2<f64>) -> (i32, i32) {
    super::cell_of(at, GRID_M)
}

/// An active detour: the goal it serves (`odom`), the waypoint driven to,
/// the way's length from the waypoint to the goal, and when it was planned.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Detour {
    pub(super) goal: Vector2<f64>,
    pub(super) waypoint: Vector2<f64>,
    pub(super) beyond_m: f64,
    pub(super) planned: f64,
}

/// The search raster: each cell's clearance to the nearest keep-out cell
/// marked within the radius it was marked with (else infinite), m.
#[derive(Clone, Debug)]
pub(super) struct Raster {
    origin: Vector2<f64>,
    w: usize,
    h: usize,
    clearance: Vec<f32>,
}

impl Raster {
    /// An empty raster covering `lo`..`hi` (`odom`): nothing near anywhere.
    pub(super) fn new(lo: Vector2<f64>, hi: Vector2<f64>) -> Self {
        let w = (((hi.x - lo.x) / GRID_M).ceil() as usize).max(1);
        let h = (((hi.y - lo.y) / GRID_M).ceil() as usize).max(1);
        Self { origin: lo, w, h, clearance: vec![f32::INFINITY; w * h] }
    }

    fn index(&self, at: &Vector2<f64>) -> Option<usize> {
        let (i, j) = (((at.x - self.origin.x) / GRID_M).floor(), ((at.y - self.origin.y) / GRID_M).floor());
        (i >= 0.0 && j >= 0.0 && (i as usize) < self.w && (j as usize) < self.h)
            .then(|| j as usize * self.w + i as usize)
    }

    fn centre(&self, k: usize) -> Vector2<f64> {
        let (i, j) = (k % self.w, k / self.w);
        self.origin + Vector2::new((i as f64 + 0.5) * GRID_M, (j as f64 + 0.5) * GRID_M)
    }

    /// Marks a keep-out cell at `at`: every raster cell within `soft` of it
    /// gets the smaller of its clearance and its distance to it.
    pub(super) fn mark(&mut self, at: &Vector2<f64>, soft: f64) {
        let reach = (soft / GRID_M).ceil() as i64;
        let (ci, cj) =
            (((at.x - self.origin.x) / GRID_M).floor() as i64, ((at.y - self.origin.y) / GRID_M).floor() as i64);
        for dj in -reach..=reach {
            let j = cj + dj;
            if j < 0 || j >= self.h as i64 {
                continue;
            }
            for di in -reach..=reach {
                let i = ci + di;
                if i < 0 || i >= self.w as i64 {
                    continue;
                }
                let k = j as usize * self.w + i as usize;
                let d = (self.centre(k) - at).norm() as f32;
                if d < self.clearance[k] {
                    self.clearance[k] = d;
                }
            }
        }
    }

    /// Whether the straight segment `a` → `b` keeps `lethal` clearance,
    /// except within `exempt` m of `a` (where the robot stands now: a robot
    /// already near something must still be able to leave it).
    pub(super) fn line_clear(&self, a: &Vector2<f64>, b: &Vector2<f64>, lethal: f64, exempt: f64) -> bool {
        let n = ((b - a).norm() / (GRID_M / 2.0)).ceil().max(1.0) as usize;
        (0..=n).all(|s| {
            let q = a + (b - a) * (s as f64 / n as f64);
            (q - a).norm() <= exempt || self.index(&q).is_none_or(|k| f64::from(self.clearance[k]) >= lethal)
        })
    }

    /// The cheapest way (cell centres, `from` first, `to` last) from `from`
    /// to within `tolerance` of `to` that keeps `lethal` clearance (cells
    /// within `exempt` of `from` excepted), each step's length weighted up
    /// by `NEAR_COST` where the clearance is below `soft`. `None` when
    /// there is none inside the raster.
    pub(super) fn search(
        &self,
        from: &Vector2<f64>,
        to: &Vector2<f64>,
        tolerance: f64,
        lethal: f64,
        soft: f64,
        exempt: f64,
    ) -> Option<Vec<Vector2<f64>>> {
        let start = self.index(from)?;
        let passable = |k: usize| f64::from(self.clearance[k]) >= lethal || (self.centre(k) - from).norm() <= exempt;
        let weight = |k: usize| {
            let c = f64::from(self.clearance[k]);
            if c >= soft { 1.0 } else { 1.0 + NEAR_COST * ((soft - c) / (soft - lethal).max(1e-6)).min(1.0) }
        };
        let heuristic = |k: usize| {
            let d = self.centre(k) - to;
            let (dx, dy) = (d.x.abs(), d.y.abs());
            (dx.max(dy) + (std::f64::consts::SQRT_2 - 1.0) * dx.min(dy) - tolerance).max(0.0)
        };
        let mut cost = vec![f64::INFINITY; self.w * self.h];
        let mut came = vec![usize::MAX; self.w * self.h];
        let mut open = BinaryHeap::new();
        cost[start] = 0.0;
        open.push(Open { f: heuristic(start), k: start });
        while let Some(Open { k, .. }) = open.pop() {
            if (self.centre(k) - to).norm() <= tolerance {
                let mut way = vec![self.centre(k)];
                let mut at = k;
                while came[at] != usize::MAX {
                    at = came[at];
                    way.push(self.centre(at));
                }
                way.reverse();
                way[0] = *from;
                return Some(way);
            }
            let (i, j) = ((k % self.w) as i64, (k / self.w) as i64);
            for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)] {
                let (ni, nj) = (i + di, j + dj);
                if ni < 0 || nj < 0 || ni >= self.w as i64 || nj >= self.h as i64 {
                    continue;
                }
                let n = nj as usize * self.w + ni as usize;
                if !passable(n) {
                    continue;
                }
                let step = if di != 0 && dj != 0 { std::f64::consts::SQRT_2 } else { 1.0 } * GRID_M;
                let c = cost[k] + step * weight(n);
                if c + 1e-12 < cost[n] {
                    cost[n] = c;
                    came[n] = k;
                    open.push(Open { f: c + heuristic(n), k: n });
                }
            }
        }
        None
    }
}

/// An open A* node, ordered so the heap pops the least `f` (ties: the
/// lower index, so runs are reproducible).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Open {
    f: f64,
    k: usize,
}

impl Eq for Open {}

impl Ord for Open {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        other.f.total_cmp(&self.f).then_with(|| other.k.cmp(&self.k))
    }
}

impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

/// Length of a polyline, m.
pub(super) fn length(way: &[Vector2<f64>]) -> f64 {
    way.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
}

/// The waypoint of a way: the farthest of its points within
/// `WAYPOINT_REACH_M` along it that the robot at `way[0]` sees in a
/// straight line with `lethal` clearance; its index.
pub(super) fn waypoint(raster: &Raster, way: &[Vector2<f64>], lethal: f64, exempt: f64) -> usize {
    let mut along = 0.0;
    let mut best = way.len().min(2) - 1;
    for k in 1..way.len() {
        along += (way[k] - way[k - 1]).norm();
        if along > WAYPOINT_REACH_M {
            break;
        }
        if raster.line_clear(&way[0], &way[k], lethal, exempt) {
            best = k;
        }
    }
    best
}

impl RobotState {
    /// Clearance the detour's way keeps from keep-out cells (the body's
    /// half-width and the guard's margin) and the radius below which it
    /// costs more (the sweep disc's), m.
    fn detour_clearances(p: &FollowParams) -> (f64, f64) {
        (p.half_width_m + p.guard_margin_m, p.sweep_radius_m)
    }

    /// Keeps the grid: drops cells too old, too far, or looked at and seen
    /// free by this frame; adds the memory's standing keep-out cells.
    pub(super) fn update_grid(&mut self, input: &StepInput<'_>, p: &FollowParams) {
        let here = input.pose.position();
        let cloud = input.cloud;
        self.grid.cells.retain(|_, g| {
            if input.stamp - g.stamp > GRID_KEEP_S || (g.at - here).norm() > GRID_RANGE_M {
                return false;
            }
            let b = input.pose.inverse_transform(&g.at);
            b.norm() > p.memory_range_m || !Self::seen_free(&g.cell, &b, cloud, input, p)
        });
        let standing: Vec<GridCell> =
            self.standing_keep_out().map(|(at, cell, stamp)| GridCell { at, cell, stamp }).collect();
        for g in standing {
            self.grid.cells.insert(grid_key(&g.at), g);
        }
    }

    /// The way from the robot to `goal` (`odom`) on the grid, and the
    /// raster it was searched on; `None` when the grid shows none.
    fn detour_way(
        &self,
        input: &StepInput<'_>,
        goal: &Vector2<f64>,
        p: &FollowParams,
    ) -> Option<(Raster, Vec<Vector2<f64>>)> {
        let (lethal, soft) = Self::detour_clearances(p);
        let here = input.pose.position();
        // A far goal: toward it along its line, as far as the search reaches.
        let to = if (goal - here).norm() > SEARCH_REACH_M {
            here + (goal - here).normalize() * SEARCH_REACH_M
        } else {
            *goal
        };
        let lo = Vector2::new(here.x.min(to.x), here.y.min(to.y)) - Vector2::repeat(SEARCH_MARGIN_M);
        let hi = Vector2::new(here.x.max(to.x), here.y.max(to.y)) + Vector2::repeat(SEARCH_MARGIN_M);
        let mut raster = Raster::new(lo, hi);
        for g in self.grid.cells.values() {
            if g.at.x >= lo.x - soft && g.at.x <= hi.x + soft && g.at.y >= lo.y - soft && g.at.y <= hi.y + soft {
                raster.mark(&g.at, soft);
            }
        }
        // This frame's cells too (a person standing still is in the cloud,
        // not in the grid): the way starts among them.
        for c in &self.cloud.cells {
            if c.keeps_out() {
                raster.mark(&input.pose.transform(&Vector2::new(f64::from(c.x), f64::from(c.y))), soft);
            }
        }
        let tolerance = input.goal.position_tolerance.clamp(GRID_M, 0.5);
        let exempt = lethal;
        let way = raster.search(&here, &to, tolerance, lethal, soft, exempt)?;
        Some((raster, way))
    }

    /// Whether the straight line from `here` to `goal` (`odom`) keeps the
    /// sweep disc's clearance from every grid cell beyond the body's
    /// clearance round `here`: the paths' own way, which needs no detour.
    fn straight_clear(&self, here: &Vector2<f64>, goal: &Vector2<f64>, p: &FollowParams) -> bool {
        let (lethal, soft) = Self::detour_clearances(p);
        let lo = Vector2::new(here.x.min(goal.x), here.y.min(goal.y)) - Vector2::repeat(1.0);
        let hi = Vector2::new(here.x.max(goal.x), here.y.max(goal.y)) + Vector2::repeat(1.0);
        let mut raster = Raster::new(lo, hi);
        for g in self.grid.cells.values() {
            if g.at.x >= lo.x - soft && g.at.x <= hi.x + soft && g.at.y >= lo.y - soft && g.at.y <= hi.y + soft {
                raster.mark(&g.at, soft);
            }
        }
        // The last stretch only needs the body's clearance: a goal before a
        // landmark lies nearer it than the sweep disc's radius.
        let span = (goal - here).norm();
        let before = if span > soft { goal - (goal - here) * (soft / span) } else { *here };
        raster.line_clear(here, &before, soft, lethal) && raster.line_clear(&before, goal, lethal, 0.0)
    }

    /// Plans (or re-plans) a detour to `goal` (`odom`): `true` when the
    /// grid shows a way whose waypoint is not the goal itself in a straight
    /// line (which the paths already try).
    pub(super) fn plan_detour(&mut self, input: &StepInput<'_>, goal: &Vector2<f64>, p: &FollowParams) -> bool {
        if !p.detour {
            return false;
        }
        let (lethal, _) = Self::detour_clearances(p);
        if self.straight_clear(&input.pose.position(), goal, p) {
            self.detour = None;
            return false;
        }
        let Some((raster, way)) = self.detour_way(input, goal, p) else {
            tracing::debug!(stamp = input.stamp, goal = ?goal, "no detour: the grid shows no way");
            self.detour = None;
            return false;
        };
        // A way much longer than the straight line leads through places the
        // camera has not looked at (it looks only ahead, and unknown counts
        // as free): such a detour is no better than asking.
        let straight = (goal - input.pose.position()).norm();
        let total = length(&way) + (goal - way[way.len() - 1]).norm();
        if total > DETOUR_STRETCH * straight + DETOUR_SLACK_M {
            tracing::debug!(stamp = input.stamp, total, straight, "no detour: the way is too long");
            self.detour = None;
            return false;
        }
        let k = waypoint(&raster, &way, lethal, lethal);
        let waypoint_at = way[k];
        let beyond_m = length(&way[k..]) + (goal - way[way.len() - 1]).norm();
        tracing::debug!(stamp = input.stamp, waypoint = ?waypoint_at, beyond_m, "detour");
        self.detour = Some(Detour { goal: *goal, waypoint: waypoint_at, beyond_m, planned: input.stamp });
        true
    }

    /// The position to drive to this frame for `goal` (`odom`) and the
    /// distance left to the goal along the way: the detour's waypoint while
    /// one is active (re-planned when passed or every `REPLAN_S`, dropped
    /// once the straight line to the goal is clear), else the goal itself.
    pub(super) fn detour_target(
        &mut self,
        input: &StepInput<'_>,
        goal: &Vector2<f64>,
        p: &FollowParams,
    ) -> Option<(Vector2<f64>, f64)> {
        let d = self.detour.filter(|d| (d.goal - goal).norm() < 0.5)?;
        let here = input.pose.position();
        if self.straight_clear(&here, goal, p) {
            tracing::debug!(stamp = input.stamp, "detour done: the way to the goal is clear");
            self.detour = None;
            return None;
        }
        if ((d.waypoint - here).norm() <= WAYPOINT_PASSED_M || input.stamp - d.planned >= REPLAN_S)
            && !self.plan_detour(input, goal, p)
        {
            return None;
        }
        let d = self.detour?;
        Some((d.waypoint, (d.waypoint - here).norm() + d.beyond_m))
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;

    use super::{Raster, length, waypoint};

    /// A raster of 12 m × 8 m from (−2, −4) with a no-go patch 6 m wide
    /// (y −3 … 3) and 1 m deep (x 3 … 4) across the x axis.
    fn patch() -> Raster {
        let mut r = Raster::new(Vector2::new(-2.0, -4.0), Vector2::new(10.0, 4.0));
        for i in 0..=10 {
            for j in -30..=30 {
                r.mark(&Vector2::new(3.0 + 0.1 * f64::from(i), 0.1 * f64::from(j)), 0.65);
            }
        }
        r
    }

    #[test]
    fn the_way_goes_round_a_patch_wider_than_the_paths_reach() {
        let r = patch();
        let (from, to) = (Vector2::new(0.0, 0.0), Vector2::new(8.0, 0.0));
        assert!(!r.line_clear(&from, &to, 0.385, 0.385));
        let way = r.search(&from, &to, 0.3, 0.385, 0.65, 0.385).expect("a way round");
        assert!((way[0] - from).norm() < 1e-9);
        assert!((way.last().unwrap() - to).norm() <= 0.3);
        // Round one end, keeping the body clear of the patch.
        let widest = way.iter().map(|q| q.y.abs()).fold(0.0, f64::max);
        assert!(widest > 3.385, "{widest}");
        for q in &way {
            let inside_x = q.x > 3.0 - 0.385 && q.x < 4.0 + 0.385;
            assert!(!(inside_x && q.y.abs() < 3.0 + 0.38), "{q:?} too near the patch");
        }
        // Not much longer than round its corner.
        let corner = Vector2::new(3.5, 3.5);
        let round = (corner - from).norm() + (to - corner).norm();
        assert!(length(&way) < round + 1.5, "{} vs {round}", length(&way));
    }

    #[test]
    fn the_waypoint_is_the_farthest_point_in_sight_within_reach() {
        let r = patch();
        let from = Vector2::new(0.0, 0.0);
        let way = r.search(&from, &Vector2::new(8.0, 0.0), 0.3, 0.385, 0.65, 0.385).unwrap();
        let k = waypoint(&r, &way, 0.385, 0.385);
        assert!(k > 0);
        assert!(length(&way[..=k]) <= super::WAYPOINT_REACH_M + 1e-9);
        assert!(r.line_clear(&from, &way[k], 0.385, 0.385));
        // It leads off the blocked line, toward the end the way goes round.
        assert!(way[k].y.abs() > 1.0 && way[k].y.signum() == way[way.len() / 2].y.signum(), "{:?}", way[k]);
    }

    #[test]
    fn a_wall_with_no_gap_leaves_no_way() {
        let mut r = Raster::new(Vector2::new(-2.0, -4.0), Vector2::new(10.0, 4.0));
        for j in -45..=45 {
            r.mark(&Vector2::new(3.0, 0.1 * f64::from(j)), 0.65);
        }
        assert!(r.search(&Vector2::new(0.0, 0.0), &Vector2::new(8.0, 0.0), 0.3, 0.385, 0.65, 0.385).is_none());
        // A gap the body fits through (0.9 m) is taken.
        let mut gap = Raster::new(Vector2::new(-2.0, -4.0), Vector2::new(10.0, 4.0));
        for j in -45..=45 {
            let y = 0.1 * f64::from(j);
            if !(-0.45..=0.45).contains(&y) {
                gap.mark(&Vector2::new(3.0, y), 0.65);
            }
        }
        let way = gap.search(&Vector2::new(0.0, 0.0), &Vector2::new(8.0, 0.0), 0.3, 0.385, 0.65, 0.385);
        assert!(way.is_some_and(|w| w.iter().all(|q| (q.x - 3.0).abs() > 0.3 || q.y.abs() < 0.2)));
    }

    #[test]
    fn a_robot_standing_near_a_cell_can_still_leave_it() {
        let mut r = Raster::new(Vector2::new(-2.0, -2.0), Vector2::new(6.0, 2.0));
        r.mark(&Vector2::new(0.0, 0.3), 0.65);
        let from = Vector2::new(0.0, 0.0);
        assert!(r.search(&from, &Vector2::new(4.0, 0.0), 0.3, 0.385, 0.65, 0.0).is_none());
        assert!(r.search(&from, &Vector2::new(4.0, 0.0), 0.3, 0.385, 0.65, 0.385).is_some());
    }
}
