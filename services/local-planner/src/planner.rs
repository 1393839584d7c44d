//! Path selection: which primitive, at which rotation and scale, is free and
//! cheapest (docs/design.md §4).
//!
//! For every obstacle cell within the path range (and not beyond the goal
//! plus `goal_clear_range`, so the target itself never blocks the approach)
//! and every library rotation, the cell is turned into the library frame,
//! divided by the scale, and the lookup table gives the paths it touches.
//! A path is blocked by `points_to_block` blocking voxels (CMU: 2) or by one
//! no-go point; low points add a penalty. Among the free paths the planner
//! minimises the paper's
//!
//! `J = w_g·|heading error at the path end toward the goal|
//!    + w_o·exp(−α·min_t d_obs) + w_s·exp(−β·min_t d_sem) (+ w_low if a low bump is near)`
//!
//! where the distances come from Euclidean distance transforms of the
//! obstacle and no-go cells (0.1 m grid) sampled every 0.1 m along the path.
//! When the goal lies inside the cropped path, the path's "end" is its point
//! at the goal's range (a path end beyond the goal says nothing): the heading
//! term is the miss angle there (bearing of that point vs the goal's, CMU's
//! `dirDiff`) plus the angle between the path's heading there and the
//! straight line to the goal, so direct paths beat ones that swerve late.
//!
//! Clearance: the paths are traced by the robot's centre. One table per scale
//! level, each built with radius `clearance / scale`, so the metric clearance
//! is the same at every scale. The default 0.45 m (CMU's radius) is the
//! Husky's half-width 0.335 m plus 0.115 m of margin; at CMU's single table
//! the smallest scale (0.75) would leave only 0.34 m — none.

use nalgebra::Vector2;

use crate::cloud::ObstacleCloud;
use crate::lookup::{Grid, LookupTable, PathSet};
use crate::paths::{PATH_COUNT, PATH_RADIUS, Path, PathLibrary, SAMPLES};
use vlnav_geometry::wrap_angle;

/// Weights of the cost J (the paper publishes none; these were tuned on the
/// planner scenarios in the tests: an obstacle ahead, a no-go floor zone, a
/// corridor).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CostWeights {
    /// w_g, per radian of heading error.
    pub goal: f64,
    /// w_o and α (1/m): exp(−2·0.45) ≈ 0.41 at the clearance radius.
    pub obstacle: f64,
    pub alpha: f64,
    /// w_s and β (1/m): no-go zones are kept farther away than walls.
    pub semantic: f64,
    pub beta: f64,
    /// Added when a low (0.10–0.15 m) bump lies within the clearance.
    pub low: f64,
    /// Per radian between the path's bearing at the look-ahead distance and
    /// the course held so far (the previous frame's path at the same
    /// distance, or straight ahead): keeps the choice from flipping between
    /// near-equal detours frame after frame.
    pub turn: f64,
}

impl Default for CostWeights {
    fn default() -> Self {
        Self { goal: 1.0, obstacle: 0.6, alpha: 2.0, semantic: 1.2, beta: 1.5, low: 0.3, turn: 0.3 }
    }
}

/// The narrow-passage tables' clearance, m: the Husky's half width
/// (0.335 m), the footprint guard's margin (0.05 m) and 0.035 m for where a
/// remembered cell really is (`control/narrow.rs`).
pub const NARROW_CLEARANCE_M: f64 = 0.42;

/// Planner settings (CMU's launch values unless noted).
#[derive(Clone, Debug, PartialEq)]
pub struct PlannerParams {
    /// Metric clearance of the robot's centre line, m.
    pub clearance_m: f64,
    /// The clearance of the narrow-passage tables (`Planner::narrow`;
    /// [`NARROW_CLEARANCE_M`] with `--local-planner-narrow`, the default),
    /// m; 0 or not below `clearance_m`: none.
    pub narrow_clearance_m: f64,
    /// Library rotations, rad (authors: 9 within the camera's ±40°).
    pub rotations: Vec<f64>,
    pub default_scale: f64,
    pub min_scale: f64,
    pub scale_step: f64,
    /// Path range at full speed (CMU adjacentRange), m.
    pub default_range: f64,
    pub min_range: f64,
    pub range_step: f64,
    /// Blocking voxels that block a path.
    pub points_to_block: u8,
    /// Obstacles farther than the goal by more than this are ignored, m.
    pub goal_clear_range: f64,
    pub weights: CostWeights,
    /// Cell of the distance transforms used by the cost, m.
    pub distance_cell: f64,
    /// Where the turn term measures a path's bearing (the follower's look-ahead), m.
    pub look_ahead_m: f64,
}

impl Default for PlannerParams {
    fn default() -> Self {
        Self {
            clearance_m: 0.45,
            narrow_clearance_m: 0.0,
            rotations: (-4..=4).map(|i| (10.0 * i as f64).to_radians()).collect(),
            default_scale: 1.25,
            min_scale: 0.75,
            scale_step: 0.25,
            default_range: 4.25,
            min_range: 1.0,
            range_step: 0.5,
            points_to_block: 2,
            goal_clear_range: 0.5,
            weights: CostWeights::default(),
            distance_cell: 0.1,
            look_ahead_m: 0.5,
        }
    }
}

/// One scale with its table and the distance-transform cells of its samples.
#[derive(Clone, Debug)]
struct Level {
    scale: f64,
    table: LookupTable,
    /// For (rotation, path): cell index of the samples every 0.1 m of radius.
    cost_cells: Vec<u32>,
    cost_samples: usize,
}

/// A chosen primitive.
#[derive(Clone, Debug, PartialEq)]
pub struct Selection {
    pub path: usize,
    pub rotation: usize,
    pub rotation_rad: f64,
    pub scale: f64,
    pub range: f64,
    pub cost: f64,
    /// The path in `base_link`, cropped to the range, from the robot outward.
    pub points: Vec<Vector2<f64>>,
}

/// The outcome of one plan.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    pub selection: Option<Selection>,
    /// Free (rotation, path) pairs at the scale and range finally used.
    pub free_paths: usize,
    pub scale: f64,
    pub range: f64,
}

/// Reusable per-plan buffers.
#[derive(Clone, Debug, Default)]
pub struct Scratch {
    once: Vec<PathSet>,
    twice: Vec<PathSet>,
    no_go: Vec<PathSet>,
    low: Vec<PathSet>,
    dist_obs: DistanceField,
    dist_sem: DistanceField,
}

/// How blocked sets are computed: the table, or the brute-force reference.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    Table,
    BruteForce,
}

/// One try of the scale-and-range fallback: the path level, how far the
/// paths are checked (m) and how their blocked sets are computed.
#[derive(Clone, Copy, Debug)]
struct Pass {
    level: usize,
    range: f64,
    method: Method,
}

/// The path library, its tables and the settings.
#[derive(Clone, Debug)]
pub struct Planner {
    pub library: PathLibrary,
    pub params: PlannerParams,
    levels: Vec<Level>,
    rot_cs: Vec<(f64, f64)>,
    field: FieldGeometry,
    /// The same paths with the narrow-passage clearance
    /// (`PlannerParams::narrow_clearance_m`), if any.
    narrow: Option<Box<Planner>>,
}

/// The square distance-transform grid centred on the robot.
#[derive(Clone, Copy, Debug, PartialEq)]
struct FieldGeometry {
    cell: f64,
    half: f64,
    n: usize,
}

impl FieldGeometry {
    #[inline]
    fn index(&self, x: f64, y: f64) -> Option<u32> {
        let fx = (x + self.half) / self.cell;
        let fy = (y + self.half) / self.cell;
        if fx >= 0.0 && fy >= 0.0 && (fx as usize) < self.n && (fy as usize) < self.n {
            Some((fx as usize * self.n + fy as usize) as u32)
        } else {
            None
        }
    }
}

impl Planner {
    /// Generates the library and one lookup table per scale level.
    pub fn new(params: PlannerParams) -> Self {
        let library = PathLibrary::generate();
        let mut scales = vec![];
        let mut s = params.default_scale;
        while s >= params.min_scale - 1e-9 {
            scales.push(s);
            if params.scale_step <= 0.0 {
                break;
            }
            s -= params.scale_step;
        }
        let half = params.default_range.max(params.default_scale * PATH_RADIUS) + 0.5;
        let field =
            FieldGeometry { cell: params.distance_cell, half, n: (2.0 * half / params.distance_cell).ceil() as usize };
        let rot_cs: Vec<(f64, f64)> = params.rotations.iter().map(|a| a.sin_cos()).map(|(s, c)| (c, s)).collect();
        let levels = scales
            .iter()
            .map(|&scale| {
                let table = LookupTable::build(&library, Grid::cmu(params.clearance_m / scale));
                let cost_samples = (scale * PATH_RADIUS / 0.1).floor() as usize;
                let mut cost_cells = Vec::with_capacity(rot_cs.len() * PATH_COUNT * cost_samples);
                for &(c, s) in &rot_cs {
                    for p in &library.paths {
                        for i in 1..=cost_samples {
                            let k = Path::index_at_radius(i as f64 * 0.1 / scale + 1e-9);
                            let q = p.points[k];
                            let (x, y) = (scale * q[0], scale * q[1]);
                            let (bx, by) = (c * x - s * y, s * x + c * y);
                            cost_cells.push(field.index(bx, by).unwrap_or(u32::MAX));
                        }
                    }
                }
                Level { scale, table, cost_cells, cost_samples }
            })
            .collect();
        let narrow = (params.narrow_clearance_m > 0.0 && params.narrow_clearance_m < params.clearance_m).then(|| {
            Box::new(Planner::new(PlannerParams {
                clearance_m: params.narrow_clearance_m,
                narrow_clearance_m: 0.0,
                ..params.clone()
            }))
        });
        Self { library, params, levels, rot_cs, field, narrow }
    }

    /// The planner for narrow passages: the same paths, cost and scales
    /// with the centre line kept only `narrow_clearance_m` from obstacles
    /// (a door a little wider than the robot plus its guard margin); this
    /// planner itself where there is none.
    pub fn narrow(&self) -> &Planner {
        self.narrow.as_deref().unwrap_or(self)
    }

    /// The scale levels, largest first.
    pub fn scales(&self) -> Vec<f64> {
        self.levels.iter().map(|l| l.scale).collect()
    }

    pub fn table(&self, level: usize) -> &LookupTable {
        &self.levels[level].table
    }

    /// Plans toward `goal` (`base_link`) at `speed_fraction` of the top speed;
    /// `course` is the bearing held so far (rad, 0 = straight ahead).
    pub fn plan(
        &self,
        cloud: &ObstacleCloud,
        goal: Vector2<f64>,
        speed_fraction: f64,
        course: f64,
        scratch: &mut Scratch,
    ) -> Plan {
        self.plan_with(cloud, goal, speed_fraction, course, scratch, Method::Table)
    }

    pub fn plan_with(
        &self,
        cloud: &ObstacleCloud,
        goal: Vector2<f64>,
        speed_fraction: f64,
        course: f64,
        scratch: &mut Scratch,
        method: Method,
    ) -> Plan {
        let p = &self.params;
        let sf = speed_fraction.clamp(0.0, 1.0);
        // Scale and range with speed, as CMU's pathScaleBySpeed / pathRangeBySpeed.
        let wanted = (p.default_scale * sf).max(p.min_scale);
        let mut level = self.levels.iter().position(|l| l.scale <= wanted + 1e-9).unwrap_or(self.levels.len() - 1);
        let mut range = (p.default_range * sf).max(p.min_range);
        scratch
            .dist_obs
            .compute(&self.field, cloud.cells.iter().filter(|c| c.blocking > 0).map(|c| (c.x as f64, c.y as f64)));
        scratch.dist_sem.compute(&self.field, cloud.cells.iter().filter(|c| c.no_go).map(|c| (c.x as f64, c.y as f64)));
        loop {
            let (selection, free) = self.evaluate(cloud, goal, course, Pass { level, range, method }, scratch);
            if selection.is_some() {
                return Plan { selection, free_paths: free, scale: self.levels[level].scale, range };
            }
            if level + 1 < self.levels.len() {
                level += 1;
                range = p.default_range * self.levels[level].scale / p.default_scale;
            } else if range - p.range_step >= p.min_range - 1e-9 {
                range -= p.range_step;
            } else {
                return Plan { selection: None, free_paths: 0, scale: self.levels[level].scale, range };
            }
        }
    }

    fn blocked_sets(&self, cloud: &ObstacleCloud, goal_dist: f64, pass: Pass, scratch: &mut Scratch) {
        let Pass { level, range, method } = pass;
        let n_rot = self.rot_cs.len();
        for v in [&mut scratch.once, &mut scratch.twice, &mut scratch.no_go, &mut scratch.low] {
            v.clear();
            v.resize(n_rot, PathSet::EMPTY);
        }
        let lvl = &self.levels[level];
        let inv = 1.0 / lvl.scale;
        let limit = range.min(goal_dist + self.params.goal_clear_range);
        let limit2 = limit * limit;
        let radius = lvl.table.grid.radius;
        for cell in &cloud.cells {
            let (x, y) = (cell.x as f64, cell.y as f64);
            if x * x + y * y > limit2 {
                continue;
            }
            for (r, &(c, s)) in self.rot_cs.iter().enumerate() {
                let x2 = (c * x + s * y) * inv;
                let y2 = (-s * x + c * y) * inv;
                let near = match method {
                    Method::Table => match lvl.table.paths_near(x2, y2) {
                        Some(set) => *set,
                        None => continue,
                    },
                    Method::BruteForce => brute_force_near(&self.library, x2, y2, radius),
                };
                if near.is_empty() {
                    continue;
                }
                if cell.no_go {
                    scratch.no_go[r].union_with(&near);
                }
                if cell.blocking >= self.params.points_to_block.max(1) {
                    scratch.twice[r].union_with(&near);
                } else if cell.blocking > 0 {
                    if self.params.points_to_block <= 1 {
                        scratch.twice[r].union_with(&near);
                    } else {
                        PathSet::count_into(&mut scratch.once[r], &mut scratch.twice[r], &near);
                    }
                }
                if cell.low {
                    scratch.low[r].union_with(&near);
                }
            }
        }
    }

    fn evaluate(
        &self,
        cloud: &ObstacleCloud,
        goal: Vector2<f64>,
        course: f64,
        pass: Pass,
        scratch: &mut Scratch,
    ) -> (Option<Selection>, usize) {
        let goal_dist = goal.norm();
        self.blocked_sets(cloud, goal_dist, pass, scratch);
        let Pass { level, range, .. } = pass;
        let lvl = &self.levels[level];
        let w = &self.params.weights;
        let scale = lvl.scale;
        let crop_radius = (range / scale).min(PATH_RADIUS);
        let k_end = Path::index_at_radius(crop_radius + 1e-9).max(1);
        let goal_inside = goal_dist / scale < crop_radius;
        let k_goal = Path::index_at_radius(goal_dist / scale + 1e-9).max(1);
        let k_look = Path::index_at_radius(self.params.look_ahead_m / scale + 1e-9).clamp(1, k_end);
        // Obstacles are costed along the path only as far as they can block
        // it: up to the goal plus `goal_clear_range`. Beyond the goal (the
        // target itself when stopping before a landmark) they would push
        // every path aside and the robot would hunt left and right short of
        // a goal it can reach straight on.
        let cost_range = range.min(scale * PATH_RADIUS).min(goal_dist + self.params.goal_clear_range);
        let cost_n = (cost_range / 0.1 + 1e-9).floor() as usize;
        let cost_n = cost_n.min(lvl.cost_samples);
        let all = PathSet::all();
        let mut best: Option<(f64, usize, usize)> = None;
        let mut free_total = 0;
        for (r, &(c, s)) in self.rot_cs.iter().enumerate() {
            let blocked = {
                let mut b = scratch.twice[r];
                b.union_with(&scratch.no_go[r]);
                b
            };
            let free = all.minus(&blocked);
            free_total += free.len();
            // Goal in this rotation's library frame (angles are scale-free).
            let g = Vector2::new(c * goal.x + s * goal.y, -s * goal.x + c * goal.y) / scale;
            let goal_bearing = g.y.atan2(g.x);
            for pid in free.iter() {
                let path = &self.library.paths[pid];
                let heading_error = if goal_inside {
                    let e = path.points[k_goal];
                    wrap_angle(e[1].atan2(e[0]) - goal_bearing).abs()
                        + wrap_angle(path.tangent(k_goal) - goal_bearing).abs()
                } else {
                    let e = path.points[k_end];
                    wrap_angle((g.y - e[1]).atan2(g.x - e[0]) - path.tangent(k_end)).abs()
                };
                let look = path.points[k_look];
                let turn = wrap_angle(self.params.rotations[r] + look[1].atan2(look[0]) - course).abs();
                let mut cost = w.goal * heading_error + w.turn * turn;
                if let Some(b) = best
                    && cost >= b.0
                {
                    continue;
                }
                let cells = &lvl.cost_cells[(r * PATH_COUNT + pid) * lvl.cost_samples..][..cost_n];
                if w.obstacle > 0.0 {
                    cost += w.obstacle * (-w.alpha * scratch.dist_obs.min_along(cells)).exp();
                }
                if w.semantic > 0.0 && scratch.dist_sem.any {
                    cost += w.semantic * (-w.beta * scratch.dist_sem.min_along(cells)).exp();
                }
                if scratch.low[r].contains(pid) {
                    cost += w.low;
                }
                if best.is_none_or(|b| cost < b.0) {
                    best = Some((cost, r, pid));
                }
            }
        }
        let selection = best.map(|(cost, r, pid)| {
            let (c, s) = self.rot_cs[r];
            let points = self.library.paths[pid].points[..=k_end.min(SAMPLES - 1)]
                .iter()
                .map(|q| {
                    let (x, y) = (scale * q[0], scale * q[1]);
                    Vector2::new(c * x - s * y, s * x + c * y)
                })
                .collect();
            Selection { path: pid, rotation: r, rotation_rad: self.params.rotations[r], scale, range, cost, points }
        });
        (selection, free_total)
    }
}

/// The reference: paths within `radius` of `(x, y)` by direct distances.
pub fn brute_force_near(library: &PathLibrary, x: f64, y: f64, radius: f64) -> PathSet {
    let mut set = PathSet::EMPTY;
    let r2 = radius * radius;
    // Samples lie at radius k·0.01, so only those within ±radius of the
    // point's own radius can be near.
    let rho = x.hypot(y);
    let k0 = Path::index_at_radius((rho - radius).max(0.0));
    let k1 = Path::index_at_radius(rho + radius + 0.01);
    for p in &library.paths {
        if p.points[k0..=k1].iter().any(|q| (q[0] - x).powi(2) + (q[1] - y).powi(2) < r2) {
            set.insert(p.id);
        }
    }
    set
}

/// Euclidean distance transform of a set of cells (Felzenszwalb–Huttenlocher).
#[derive(Clone, Debug, Default)]
pub struct DistanceField {
    n: usize,
    cell: f64,
    /// Distance to the nearest marked cell, m.
    dist: Vec<f32>,
    tmp: Vec<f32>,
    v: Vec<usize>,
    z: Vec<f32>,
    f: Vec<f32>,
    out: Vec<f32>,
    /// Whether any cell is marked.
    pub any: bool,
}

const FAR: f32 = 1e6;

impl DistanceField {
    fn compute(&mut self, g: &FieldGeometry, cells: impl Iterator<Item = (f64, f64)>) {
        self.n = g.n;
        self.cell = g.cell;
        let n = g.n;
        self.tmp.clear();
        self.tmp.resize(n * n, FAR);
        self.any = false;
        for (x, y) in cells {
            if let Some(i) = g.index(x, y) {
                self.tmp[i as usize] = 0.0;
                self.any = true;
            }
        }
        self.dist.clear();
        self.dist.resize(n * n, FAR);
        if !self.any {
            return;
        }
        self.f.resize(n, 0.0);
        self.out.resize(n, 0.0);
        self.v.resize(n, 0);
        self.z.resize(n + 1, 0.0);
        // Columns (along y, contiguous), then rows (along x).
        for i in 0..n {
            self.f.copy_from_slice(&self.tmp[i * n..(i + 1) * n]);
            edt_1d(&self.f, &mut self.out, &mut self.v, &mut self.z);
            self.tmp[i * n..(i + 1) * n].copy_from_slice(&self.out);
        }
        for j in 0..n {
            for i in 0..n {
                self.f[i] = self.tmp[i * n + j];
            }
            edt_1d(&self.f, &mut self.out, &mut self.v, &mut self.z);
            for i in 0..n {
                self.dist[i * n + j] = self.out[i].sqrt() * self.cell as f32;
            }
        }
    }

    /// Minimum distance over the given cells (cells off the grid count as far).
    #[inline]
    fn min_along(&self, cells: &[u32]) -> f64 {
        let mut m = FAR;
        for &c in cells {
            if c != u32::MAX {
                m = m.min(self.dist[c as usize]);
            }
        }
        m as f64
    }

    /// Distance at a grid cell index (tests).
    pub fn at(&self, i: usize) -> f32 {
        self.dist[i]
    }
}

/// 1-D squared distance transform of `f` (0 at sites, FAR elsewhere).
fn edt_1d(f: &[f32], d: &mut [f32], v: &mut [usize], z: &mut [f32]) {
    let n = f.len();
    let mut k = 0usize;
    // First site with a finite value.
    let Some(first) = f.iter().position(|&x| x < FAR) else {
        d.fill(FAR);
        return;
    };
    v[0] = first;
    z[0] = f32::NEG_INFINITY;
    z[1] = f32::INFINITY;
    for q in first + 1..n {
        if f[q] >= FAR {
            continue;
        }
        loop {
            let p = v[k];
            let s = ((f[q] + (q * q) as f32) - (f[p] + (p * p) as f32)) / (2.0 * q as f32 - 2.0 * p as f32);
            if s <= z[k] {
                if k == 0 {
                    v[0] = q;
                    z[1] = f32::INFINITY;
                    break;
                }
                k -= 1;
            } else {
                k += 1;
                v[k] = q;
                z[k] = s;
                z[k + 1] = f32::INFINITY;
                break;
            }
        }
    }
    k = 0;
    for (q, dq) in d.iter_mut().enumerate().take(n) {
        while z[k + 1] < q as f32 {
            k += 1;
        }
        let p = v[k];
        let diff = q as f32 - p as f32;
        *dq = diff * diff + f[p];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_transform_matches_brute_force() {
        let g = FieldGeometry { cell: 0.1, half: 2.0, n: 40 };
        let sites = [(0.55, 0.35), (-1.25, 1.05), (1.5, -1.7)];
        let mut f = DistanceField::default();
        f.compute(&g, sites.iter().copied());
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (-2.0 + (i as f64 + 0.5) * 0.1, -2.0 + (j as f64 + 0.5) * 0.1);
                let brute = sites
                    .iter()
                    .map(|&(sx, sy)| {
                        let si = ((sx + 2.0) / 0.1) as usize;
                        let sj = ((sy + 2.0) / 0.1) as usize;
                        let (cx, cy) = (-2.0 + (si as f64 + 0.5) * 0.1, -2.0 + (sj as f64 + 0.5) * 0.1);
                        (x - cx).hypot(y - cy)
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!((f.at(i * 40 + j) as f64 - brute).abs() < 1e-4, "({i},{j}) {} vs {brute}", f.at(i * 40 + j));
            }
        }
        let mut empty = DistanceField::default();
        empty.compute(&g, std::iter::empty());
        assert!(!empty.any);
        assert_eq!(empty.min_along(&[0, 5, 100]), FAR as f64);
    }
}
