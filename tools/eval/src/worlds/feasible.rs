//! Feasibility on the true map: a grid A* for the Husky's footprint.
//!
//! Used only by the world generator (and its tests) to drop instructions the
//! robot could not carry out even with a perfect map; the robot never sees
//! this map. Every solid (walls, obstacles, objects) and every no-go marking
//! (restricted zones, hazards, cables) is an obstacle; pedestrians are not
//! (they move and step aside). The robot is a disc of its half width plus a
//! margin while it drives (a skid-steer robot that drives straight through a
//! door needs its width, not its length), and needs its circumscribed radius
//! free of solids wherever it turns: at the start and at every waypoint.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use vlnav_sim::HuskyParams;
use vlnav_sim::geometry::{Shape, Vec2};
use vlnav_sim::world::World;

/// Grid resolution, metres.
pub const CELL_M: f64 = 0.1;
/// Clearance kept beyond the Husky's half width while driving, metres.
pub const DRIVE_MARGIN_M: f64 = 0.08;
/// Clearance beyond the circumscribed radius where the robot turns in place, metres.
pub const TURN_MARGIN_M: f64 = 0.02;

/// Why an instruction cannot be carried out.
#[derive(Clone, Debug, PartialEq)]
pub enum Infeasible {
    /// The robot cannot turn at this point (start or waypoint `index`).
    NoRoomToTurn { index: usize, at: [f64; 2] },
    /// No path for the footprint from waypoint `from` to the next.
    Blocked { from: usize, to: [f64; 2] },
}

impl std::fmt::Display for Infeasible {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Infeasible::NoRoomToTurn { index, at } => {
                write!(f, "no room to turn at point {index} ({:.2}, {:.2})", at[0], at[1])
            }
            Infeasible::Blocked { from, to } => {
                write!(f, "no path for the footprint from point {from} to ({:.2}, {:.2})", to[0], to[1])
            }
        }
    }
}

/// Clearance map: per cell, the distance from its centre to the nearest
/// solid and the nearest no-go marking (capped).
pub struct Grid {
    origin: Vec2,
    nx: usize,
    ny: usize,
    solid: Vec<f32>,
    nogo: Vec<f32>,
}

const CAP_M: f64 = 1.0;

impl Grid {
    /// Rasterises the world's solids and markings over their bounds plus a border.
    pub fn new(world: &World) -> Grid {
        let shapes_solid: Vec<&Shape> = world.solids.iter().map(|s| &s.shape).collect();
        let shapes_nogo: Vec<&Shape> = world.markings.iter().flat_map(|m| m.shapes.iter()).collect();
        let mut lo = Vec2::new(world.start.x, world.start.y);
        let mut hi = lo;
        for s in shapes_solid.iter().chain(shapes_nogo.iter()) {
            let (a, b) = s.bounds();
            lo = Vec2::new(lo.x.min(a.x), lo.y.min(a.y));
            hi = Vec2::new(hi.x.max(b.x), hi.y.max(b.y));
        }
        let origin = Vec2::new(lo.x - 1.0, lo.y - 1.0);
        let nx = ((hi.x - lo.x + 2.0) / CELL_M).ceil() as usize + 1;
        let ny = ((hi.y - lo.y + 2.0) / CELL_M).ceil() as usize + 1;
        let mut g = Grid { origin, nx, ny, solid: vec![CAP_M as f32; nx * ny], nogo: vec![CAP_M as f32; nx * ny] };
        for s in shapes_solid {
            g.stamp(s, true);
        }
        for s in shapes_nogo {
            g.stamp(s, false);
        }
        g
    }

    fn stamp(&mut self, s: &Shape, solid: bool) {
        let (a, b) = s.bounds();
        let (i0, j0) = self.cell_of(Vec2::new(a.x - CAP_M, a.y - CAP_M));
        let (i1, j1) = self.cell_of(Vec2::new(b.x + CAP_M, b.y + CAP_M));
        for j in j0..=j1 {
            for i in i0..=i1 {
                let p = self.centre(i, j);
                let (q, inside) = s.nearest_boundary_point(p);
                let d = if inside { 0.0 } else { (p - q).norm() };
                let slot = if solid { &mut self.solid[j * self.nx + i] } else { &mut self.nogo[j * self.nx + i] };
                if (d as f32) < *slot {
                    *slot = d as f32;
                }
            }
        }
    }

    fn cell_of(&self, p: Vec2) -> (usize, usize) {
        let i = ((p.x - self.origin.x) / CELL_M).round().clamp(0.0, (self.nx - 1) as f64) as usize;
        let j = ((p.y - self.origin.y) / CELL_M).round().clamp(0.0, (self.ny - 1) as f64) as usize;
        (i, j)
    }

    fn centre(&self, i: usize, j: usize) -> Vec2 {
        Vec2::new(self.origin.x + i as f64 * CELL_M, self.origin.y + j as f64 * CELL_M)
    }

    /// Distance from `p` to the nearest solid (capped at 1 m), by its cell.
    pub fn solid_clearance(&self, p: Vec2) -> f64 {
        let (i, j) = self.cell_of(p);
        f64::from(self.solid[j * self.nx + i])
    }

    /// Distance from `p` to the nearest solid or no-go marking (capped at 1 m).
    pub fn clearance(&self, p: Vec2) -> f64 {
        let (i, j) = self.cell_of(p);
        f64::from(self.solid[j * self.nx + i].min(self.nogo[j * self.nx + i]))
    }

    fn inside(&self, p: Vec2) -> bool {
        p.x >= self.origin.x
            && p.y >= self.origin.y
            && p.x <= self.origin.x + (self.nx - 1) as f64 * CELL_M
            && p.y <= self.origin.y + (self.ny - 1) as f64 * CELL_M
    }

    /// A* over cells whose clearance is at least `r`, 8-connected; the path
    /// length in metres, or None. A start or goal cell itself blocked counts
    /// as no path.
    pub fn path_length(&self, from: Vec2, to: Vec2, r: f64) -> Option<f64> {
        if !self.inside(from) || !self.inside(to) {
            return None;
        }
        let free = |k: usize| f64::from(self.solid[k].min(self.nogo[k])) >= r;
        let (si, sj) = self.cell_of(from);
        let (gi, gj) = self.cell_of(to);
        let (s, goal) = (sj * self.nx + si, gj * self.nx + gi);
        if !free(s) || !free(goal) {
            return None;
        }
        let h = |k: usize| {
            let (i, j) = ((k % self.nx) as f64, (k / self.nx) as f64);
            ((i - gi as f64).hypot(j - gj as f64) * 1000.0) as u64
        };
        let mut cost = vec![u64::MAX; self.nx * self.ny];
        let mut heap = BinaryHeap::new();
        cost[s] = 0;
        heap.push(Reverse((h(s), s)));
        while let Some(Reverse((_, k))) = heap.pop() {
            if k == goal {
                return Some(cost[k] as f64 / 1000.0 * CELL_M);
            }
            let (i, j) = ((k % self.nx) as i64, (k / self.nx) as i64);
            for (di, dj, c) in [
                (1, 0, 1000),
                (-1, 0, 1000),
                (0, 1, 1000),
                (0, -1, 1000),
                (1, 1, 1414),
                (1, -1, 1414),
                (-1, 1, 1414),
                (-1, -1, 1414),
            ] {
                let (ni, nj) = (i + di, j + dj);
                if ni < 0 || nj < 0 || ni >= self.nx as i64 || nj >= self.ny as i64 {
                    continue;
                }
                let n = nj as usize * self.nx + ni as usize;
                if !free(n) {
                    continue;
                }
                let c = cost[k] + c;
                if c < cost[n] {
                    cost[n] = c;
                    heap.push(Reverse((c + h(n), n)));
                }
            }
        }
        None
    }
}

/// The footprint's driving radius (half width + margin) and turning radius
/// (half diagonal + margin), metres.
pub fn radii() -> (f64, f64) {
    let p = HuskyParams::default();
    (p.width / 2.0 + DRIVE_MARGIN_M, p.length.hypot(p.width) / 2.0 + TURN_MARGIN_M)
}

/// Checks that the robot can drive from the world's start through `points`
/// in order (the route's waypoints, then where it stops), turning in place
/// at the start and every waypoint but the last. Returns the total path
/// length.
pub fn check_route(grid: &Grid, start: Vec2, points: &[Vec2]) -> Result<f64, Infeasible> {
    let (drive, turn) = radii();
    let mut total = 0.0;
    let mut from = start;
    // It turns at the start and at each waypoint; at the last point it stops.
    let mut all = vec![start];
    all.extend_from_slice(&points[..points.len().saturating_sub(1)]);
    for (k, p) in all.iter().enumerate() {
        if grid.solid_clearance(*p) < turn || grid.clearance(*p) < drive {
            return Err(Infeasible::NoRoomToTurn { index: k, at: [p.x, p.y] });
        }
    }
    for (k, p) in points.iter().enumerate() {
        total += grid.path_length(from, *p, drive).ok_or(Infeasible::Blocked { from: k, to: [p.x, p.y] })?;
        from = *p;
    }
    Ok(total)
}
