//! The obstacle cloud of one frame, in `base_link`.
//!
//! Depth pixels (every `stride`-th row and column at 640 pixels wide, the
//! same angle apart at other widths) are back-projected and
//! moved to `base_link` with the camera mount; heights are measured above the
//! floor (`ground_z` in `base_link`, 0 when `base_link` sits on the floor).
//! Like CMU's terrain classification: below `ground_height` a point is floor;
//! up to `obstacle_height` it is a low, traversable bump that only adds a
//! penalty; above it blocks; above `max_height` it is overhead (ceilings,
//! overhangs the robot passes under) and ignored. Points are downsampled on a
//! 3-D voxel grid (0.05 m) and collapsed to 2-D cells that remember how many
//! voxels above `obstacle_height` they hold, so the planner's "≥ 2 points
//! block a path" rule counts distinct voxels, not pixels. The segmenter's
//! virtual no-go points become cells of their own kind: they block and feed
//! the semantic cost.
//!
//! A depth frame also records how far it saw along each bearing
//! ([`SeenRange`]): the farthest valid point below `max_height`, floor
//! included. Where the D455 returns no depth (stereo occlusion bands left of
//! near edges, textureless or distant surfaces) the frame saw nothing, and
//! the obstacle memory (`control/memory.rs`) keeps what it remembers there.
//!
//! People the detector boxed in the frame ([`PixelBox`]) mark the cells their
//! pixels fall in: a pixel inside a person's box belongs to the person when
//! its depth is within `person_band_m` of the box's near depth (the lower
//! quartile of the box's central part, where the torso is; the background
//! around a person is farther). Each person's blocking points also give
//! where they stand ([`ObstacleCloud::people`]), for the tracker in
//! `control/memory.rs`.

use nalgebra::{Vector2, Vector3};
use vlnav_geometry::camera::Camera;
pub use vlnav_geometry::camera::PixelBox;
use vlnav_geometry::depth::DepthView;
use vlnav_geometry::wrap_angle;

/// Height classification and downsampling settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CloudParams {
    /// z of the floor in `base_link`, m.
    pub ground_z: f64,
    /// Below this height a point is floor, m.
    pub ground_height: f64,
    /// Above this height a point blocks; between the two it adds a penalty, m.
    pub obstacle_height: f64,
    /// Above this height a point is overhead and ignored, m.
    pub max_height: f64,
    /// Points farther than this (horizontally) are ignored, m (CMU adjacentRange).
    pub max_range: f64,
    /// Downsampling voxel, m.
    pub voxel: f64,
    /// Use every `stride`-th depth row and column of a 640-pixel-wide
    /// image (the D455's), and the same angular spacing at other widths
    /// ([`CloudParams::stride_for`]).
    pub stride: usize,
    /// A pixel in a person's box belongs to the person within this depth of
    /// the box's near depth, m (a body's depth plus the D455's error at a
    /// few metres).
    pub person_band_m: f64,
}

impl CloudParams {
    /// The stride for an image `width` pixels wide: `stride` scaled to the
    /// width, at least 1, so the sampled rows and columns lie the same angle
    /// apart at any resolution (0.67° on the D455's 87° view). A 160-pixel
    /// image sampled every 4th column had one column every 2.7°: a door
    /// jamb seen end-on fell between columns, and most of the 1° bins of
    /// what the frame saw (`SeenRange`) held no column, so a remembered
    /// cell there was never forgotten and a person walking there never seen
    /// to move (docs/evaluation.md, "Depth sampled at the same angle").
    pub fn stride_for(&self, width: u32) -> usize {
        vlnav_geometry::camera::scaled_stride(self.stride, width)
    }
}

impl Default for CloudParams {
    fn default() -> Self {
        Self {
            ground_z: 0.0,
            ground_height: 0.10,
            obstacle_height: 0.15,
            max_height: 1.2,
            max_range: 4.25,
            voxel: 0.05,
            stride: 4,
            person_band_m: 0.4,
        }
    }
}

/// One occupied 2-D cell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell {
    pub x: f32,
    pub y: f32,
    /// Distinct voxels above `obstacle_height` in this column (saturating).
    pub blocking: u8,
    /// Whether a low (penalty) voxel is in the column.
    pub low: bool,
    /// A virtual point from the segmenter's no-go mask.
    pub no_go: bool,
    /// 0, or k when the frame's k-th person box covers one of the column's
    /// blocking points (index k − 1 of [`ObstacleCloud::people`]).
    pub person: u8,
}

impl Cell {
    /// What the robot's body must not take in: an obstacle (at least two
    /// voxels above the floor) or a no-go region (a marked zone, a cable, a
    /// hazard: soft contact is entering one, docs/design.md §6).
    pub fn keeps_out(&self) -> bool {
        self.blocking >= 2 || self.no_go
    }
}

/// The downsampled obstacles of one frame.
#[derive(Clone, Debug, Default)]
pub struct ObstacleCloud {
    pub cells: Vec<Cell>,
    /// Points that survived the height and range filters (before downsampling).
    pub raw_points: usize,
    /// How far the frame saw along each bearing; `None` for clouds not built
    /// from a depth frame (synthetic points), whose coverage is unknown.
    pub seen: Option<SeenRange>,
    /// Where each person box's blocking points stand on average, `base_link`
    /// (`None`: the box held none), in the order of the boxes given.
    pub people: Vec<Option<Vector2<f64>>>,
}

/// The farthest horizontal range a depth frame measured along each bearing
/// from the camera, in 1° bins, `base_link`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SeenRange {
    /// The camera's position in `base_link` (x, y), m.
    origin: Vector2<f64>,
    /// Range per bin, m (0: nothing measured); bin 0 starts at bearing −π.
    range: Vec<f32>,
    /// Range of the nearest blocking point per bin, m (∞: none).
    nearest_obstacle: Vec<f32>,
}

impl SeenRange {
    const BINS: usize = 360;

    /// Nothing seen yet, from a camera at `origin` (`base_link`, m).
    pub fn new(origin: Vector2<f64>) -> Self {
        Self { origin, range: vec![0.0; Self::BINS], nearest_obstacle: vec![f32::INFINITY; Self::BINS] }
    }

    fn bin(&self, d: &Vector2<f64>) -> usize {
        self.bin_of(d.y.atan2(d.x))
    }

    /// The bin of a bearing in [−π, π] (what `atan2` returns).
    fn bin_of(&self, bearing: f64) -> usize {
        let f = (bearing + std::f64::consts::PI) / std::f64::consts::TAU;
        ((f * Self::BINS as f64) as usize).min(Self::BINS - 1)
    }

    /// Records a measured point at (x, y) in `base_link`.
    pub fn record(&mut self, x: f64, y: f64) {
        let d = Vector2::new(x, y) - self.origin;
        if self.range.is_empty() {
            return;
        }
        let k = self.bin(&d);
        self.range[k] = self.range[k].max(d.norm() as f32);
    }

    /// Records a measured point at (x, y) in `base_link` that blocks (it
    /// ends the free space along its bearing).
    pub fn record_obstacle(&mut self, x: f64, y: f64) {
        self.record(x, y);
        let d = Vector2::new(x, y) - self.origin;
        if self.nearest_obstacle.is_empty() {
            return;
        }
        let k = self.bin(&d);
        self.nearest_obstacle[k] = self.nearest_obstacle[k].min(d.norm() as f32);
    }

    /// Whether the frame saw free space at least `margin` m beyond `p`
    /// (`base_link`) along every bearing within `half_angle` rad of its own:
    /// measured that far, and nothing blocking nearer. (A bin keeps the
    /// farthest range it measured, so the bin an object's outline falls in
    /// may hold only rays that passed it by; the caller's `half_angle` covers
    /// the point's own extent and the outline's quantisation, so a point on
    /// a standing object's outline never counts as seen through.)
    pub fn free_beyond(&self, p: &Vector2<f64>, margin: f64, half_angle: f64) -> bool {
        let d = p - self.origin;
        if self.range.is_empty() || self.nearest_obstacle.is_empty() {
            return false;
        }
        let need = d.norm() + margin;
        let (bearing, half) = (d.y.atan2(d.x), half_angle.max(0.0));
        let (lo, hi) = (self.bin_of(wrap_angle(bearing - half)), self.bin_of(wrap_angle(bearing + half)));
        let n = (hi + Self::BINS - lo) % Self::BINS;
        (0..=n).all(|o| {
            let j = (lo + o) % Self::BINS;
            f64::from(self.range[j].min(self.nearest_obstacle[j])) >= need
        })
    }

    /// The camera's position in `base_link` (x, y), m.
    pub fn origin(&self) -> Vector2<f64> {
        self.origin
    }

    /// Every bearing the frame measured, in bin order: (bearing from the
    /// camera in `base_link`, rad; how far it saw free, m; where a blocking
    /// point ended it, m, if one did within what it measured). What the
    /// frontier search (`control/frontier.rs`) marks seen.
    pub fn rays(&self) -> impl Iterator<Item = (f64, f64, Option<f64>)> + '_ {
        let step = std::f64::consts::TAU / Self::BINS as f64;
        self.range.iter().zip(&self.nearest_obstacle).enumerate().filter(|(_, (r, _))| **r > 0.0).map(
            move |(k, (&r, &o))| {
                let bearing = -std::f64::consts::PI + (k as f64 + 0.5) * step;
                let blocked = (o <= r).then_some(f64::from(o));
                (bearing, f64::from(r.min(o)), blocked)
            },
        )
    }

    /// Whether the frame saw as far as `p` (`base_link`) along its bearing,
    /// within `margin` m.
    pub fn reaches(&self, p: &Vector2<f64>, margin: f64) -> bool {
        let d = p - self.origin;
        !self.range.is_empty() && f64::from(self.range[self.bin(&d)]) >= d.norm() - margin
    }
}

impl ObstacleCloud {
    pub fn blocking_cells(&self) -> usize {
        self.cells.iter().filter(|c| c.blocking > 0).count()
    }
}

/// The multiples of `stride` below `n` within [`lo`, `hi`]: the sampled
/// rows (or columns) of the cloud that fall in that span of the image.
fn strided(lo: f64, hi: f64, n: usize, stride: usize) -> impl Iterator<Item = usize> {
    let first = lo.max(0.0).ceil() as usize;
    let first = first.div_ceil(stride) * stride;
    let end = if hi < 0.0 { 0 } else { (hi.floor() as usize + 1).min(n) };
    (first..end).step_by(stride)
}

/// Reusable downsampling buffers (a dense voxel bitmap around the robot).
#[derive(Clone, Debug)]
pub struct CloudBuilder {
    params: CloudParams,
    nx: usize,
    ny: usize,
    nz: usize,
    x0: f64,
    y0: f64,
    occupied: Vec<u64>,
    column: Vec<u32>,
    cells: Vec<Cell>,
    raw: usize,
    seen: Option<SeenRange>,
    people: Vec<Option<Vector2<f64>>>,
}

const NO_CELL: u32 = u32::MAX;

impl CloudBuilder {
    pub fn new(params: CloudParams) -> Self {
        let r = params.max_range;
        let nx = ((2.0 * r) / params.voxel).ceil() as usize + 1;
        let ny = nx;
        let nz = (((params.max_height - params.ground_height) / params.voxel).ceil() as usize).max(1) + 1;
        Self {
            params,
            nx,
            ny,
            nz,
            x0: -r,
            y0: -r,
            occupied: vec![0; (nx * ny * nz).div_ceil(64)],
            column: vec![NO_CELL; nx * ny],
            cells: Vec::new(),
            raw: 0,
            seen: None,
            people: Vec::new(),
        }
    }

    pub fn params(&self) -> &CloudParams {
        &self.params
    }

    fn clear(&mut self) {
        for c in &self.cells {
            let ix = ((c.x as f64 - self.x0) / self.params.voxel) as usize;
            let iy = ((c.y as f64 - self.y0) / self.params.voxel) as usize;
            self.column[ix * self.ny + iy] = NO_CELL;
        }
        self.cells.clear();
        self.occupied.fill(0);
        self.raw = 0;
        self.seen = None;
        self.people.clear();
    }

    fn cell_mut(&mut self, ix: usize, iy: usize) -> &mut Cell {
        let slot = ix * self.ny + iy;
        if self.column[slot] == NO_CELL {
            self.column[slot] = self.cells.len() as u32;
            let v = self.params.voxel;
            self.cells.push(Cell {
                x: (self.x0 + (ix as f64 + 0.5) * v) as f32,
                y: (self.y0 + (iy as f64 + 0.5) * v) as f32,
                blocking: 0,
                low: false,
                no_go: false,
                person: 0,
            });
        }
        let i = self.column[slot] as usize;
        &mut self.cells[i]
    }

    fn column_of(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let fx = (x - self.x0) / self.params.voxel;
        let fy = (y - self.y0) / self.params.voxel;
        if fx >= 0.0 && fy >= 0.0 && (fx as usize) < self.nx && (fy as usize) < self.ny {
            Some((fx as usize, fy as usize))
        } else {
            None
        }
    }

    /// Adds one `base_link` point (height classified against the floor).
    #[inline]
    pub fn add_point(&mut self, x: f64, y: f64, z: f64) {
        let p = &self.params;
        let h = z - p.ground_z;
        if !(h >= p.ground_height && h <= p.max_height) || x * x + y * y > p.max_range * p.max_range {
            return;
        }
        let Some((ix, iy)) = self.column_of(x, y) else { return };
        self.raw += 1;
        let iz = (((h - p.ground_height) / p.voxel) as usize).min(self.nz - 1);
        let bit = (ix * self.ny + iy) * self.nz + iz;
        let (w, b) = (bit / 64, 1u64 << (bit % 64));
        if self.occupied[w] & b != 0 {
            return;
        }
        self.occupied[w] |= b;
        let blocking = h > p.obstacle_height;
        let cell = self.cell_mut(ix, iy);
        if blocking {
            cell.blocking = cell.blocking.saturating_add(1);
        } else {
            cell.low = true;
        }
    }

    /// Adds a virtual no-go point (any height: it always blocks).
    pub fn add_no_go(&mut self, x: f64, y: f64) {
        if x * x + y * y > self.params.max_range * self.params.max_range {
            return;
        }
        if let Some((ix, iy)) = self.column_of(x, y) {
            self.cell_mut(ix, iy).no_go = true;
        }
    }

    /// The near depth of each person box, m (`None`: no valid depth in its
    /// central part): the lower quartile of the valid depth sampled in the
    /// box's middle half across and middle 70 % down.
    fn person_depths(&self, cam: &Camera, depth: &DepthView<'_>, people: &[PixelBox]) -> Vec<Option<f64>> {
        let stride = self.params.stride_for(cam.width);
        let (lo, hi) = (cam.depth_min_m * 1000.0, cam.depth_max_m * 1000.0);
        people
            .iter()
            .map(|b| {
                let (w, h) = (b.x_max - b.x_min, b.y_max - b.y_min);
                let (u0, u1) = (b.x_min + 0.25 * w, b.x_max - 0.25 * w);
                let (v0, v1) = (b.y_min + 0.15 * h, b.y_max - 0.15 * h);
                let mut d: Vec<f64> = strided(v0, v1, depth.height(), stride)
                    .flat_map(|v| strided(u0, u1, depth.width(), stride).map(move |u| depth.mm(u, v) as f64))
                    .filter(|&z| z > 0.0 && z > lo && z < hi)
                    .collect();
                if d.is_empty() {
                    return None;
                }
                let q = d.len() / 4;
                let (_, near, _) = d.select_nth_unstable_by(q, f64::total_cmp);
                Some(*near / 1000.0)
            })
            .collect()
    }

    /// Adds the depth frame's points; pixels of the people in `people` (at
    /// most 255) mark their cells and give where each stands.
    pub fn add_depth(&mut self, cam: &Camera, depth: &DepthView<'_>, people: &[PixelBox]) {
        let people = &people[..people.len().min(usize::from(u8::MAX))];
        let near = self.person_depths(cam, depth, people);
        let mut sums = vec![(0.0, 0.0, 0usize); people.len()];
        let k = cam.intrinsics;
        let t = cam.mount.optical_to_base();
        let stride = self.params.stride_for(cam.width);
        let (lo, hi) = (cam.depth_min_m * 1000.0, cam.depth_max_m * 1000.0);
        let origin = t.apply(&Vector3::zeros());
        let mut seen = SeenRange::new(Vector2::new(origin.x, origin.y));
        let top = self.params.ground_z + self.params.max_height;
        let blocking_from = self.params.ground_z + self.params.obstacle_height;
        for v in (0..depth.height()).step_by(stride) {
            let yn = (v as f64 - k.cy) / k.fy;
            for u in (0..depth.width()).step_by(stride) {
                let mm = depth.mm(u, v);
                let z = mm as f64;
                if mm == 0 || z <= lo || z >= hi {
                    continue;
                }
                let zm = z / 1000.0;
                let p = t.apply(&Vector3::new((u as f64 - k.cx) / k.fx * zm, yn * zm, zm));
                if p.z <= top {
                    if p.z > blocking_from {
                        seen.record_obstacle(p.x, p.y);
                    } else {
                        seen.record(p.x, p.y);
                    }
                }
                self.add_point(p.x, p.y, p.z);
                if people.is_empty() || p.z <= blocking_from || p.z > top {
                    continue;
                }
                let person = people.iter().zip(&near).position(|(b, near)| {
                    near.is_some_and(|n| (zm - n).abs() <= self.params.person_band_m) && b.contains(u as f64, v as f64)
                });
                if let (Some(i), Some((ix, iy))) = (person, self.column_of(p.x, p.y)) {
                    let cell = self.column[ix * self.ny + iy];
                    if cell != NO_CELL {
                        self.cells[cell as usize].person = i as u8 + 1;
                        let s = &mut sums[i];
                        *s = (s.0 + p.x, s.1 + p.y, s.2 + 1);
                    }
                }
            }
        }
        self.seen = Some(seen);
        self.people =
            sums.into_iter().map(|(x, y, n)| (n > 0).then(|| Vector2::new(x / n as f64, y / n as f64))).collect();
    }

    /// Builds a cloud from `base_link` points and no-go points (benchmarks, tests).
    pub fn from_points(&mut self, points: &[[f64; 3]], no_go: &[[f64; 3]]) -> ObstacleCloud {
        self.clear();
        for p in points {
            self.add_point(p[0], p[1], p[2]);
        }
        for p in no_go {
            self.add_no_go(p[0], p[1]);
        }
        self.finish()
    }

    /// Builds a cloud from a depth frame, the people boxed in it and no-go points.
    pub fn from_depth(
        &mut self,
        cam: &Camera,
        depth: &DepthView<'_>,
        people: &[PixelBox],
        no_go: &[[f64; 3]],
    ) -> ObstacleCloud {
        self.clear();
        self.add_depth(cam, depth, people);
        for p in no_go {
            self.add_no_go(p[0], p[1]);
        }
        self.finish()
    }

    fn finish(&mut self) -> ObstacleCloud {
        ObstacleCloud {
            cells: self.cells.clone(),
            raw_points: self.raw,
            seen: self.seen.clone(),
            people: self.people.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vlnav_geometry::camera::{Intrinsics, Mount};
    use vlnav_geometry::depth::encode_depth_mm;

    #[test]
    fn heights_split_floor_penalty_blocking_and_overhead() {
        let mut b = CloudBuilder::new(CloudParams::default());
        let c = b.from_points(
            &[
                [2.0, 0.0, 0.05],  // floor
                [2.0, 1.0, 0.12],  // low bump
                [2.0, -1.0, 0.5],  // obstacle
                [2.0, -1.0, 0.51], // same voxel: counted once
                [2.0, -1.0, 0.7],  // same column, another voxel
                [2.0, 2.0, 2.0],   // overhead
                [6.0, 0.0, 0.5],   // out of range
            ],
            &[[1.0, 0.5, 0.5]],
        );
        assert_eq!(c.raw_points, 4);
        assert_eq!(c.cells.len(), 3);
        let low = c.cells.iter().find(|c| c.low).unwrap();
        assert_eq!(low.blocking, 0);
        assert!((low.y - 1.0).abs() < 0.05);
        let obstacle = c.cells.iter().find(|c| c.blocking > 0).unwrap();
        assert_eq!(obstacle.blocking, 2);
        assert!(c.cells.iter().any(|c| c.no_go && c.blocking == 0));
        // A rebuilt cloud starts empty.
        let c = b.from_points(&[[1.0, 0.0, 0.3]], &[]);
        assert_eq!(c.cells.len(), 1);
        assert_eq!(c.cells[0].blocking, 1);
    }

    #[test]
    fn depth_frame_of_a_wall_and_floor_becomes_wall_cells_only() {
        // Camera 0.5 m up looking level; a wall 2 m ahead, the floor below the horizon.
        let cam = Camera {
            width: 64,
            height: 48,
            intrinsics: Intrinsics { fx: 40.0, fy: 40.0, cx: 31.5, cy: 23.5 },
            mount: Mount { translation: Vector3::new(0.2, 0.0, 0.5), ..Mount::default() },
            depth_min_m: 0.3,
            depth_max_m: 10.0,
        };
        let mut depth = vec![0.0; 64 * 48];
        for v in 0..48 {
            for u in 0..64 {
                let yn = (v as f64 - 23.5) / 40.0;
                // Floor hit when the ray goes down before reaching the wall.
                let floor_z = if yn > 0.0 { 0.5 / yn } else { f64::INFINITY };
                depth[v * 64 + u] = floor_z.min(1.8);
            }
        }
        let bytes = encode_depth_mm(&depth);
        let view = DepthView::new(64, 48, &bytes).unwrap();
        let mut b = CloudBuilder::new(CloudParams { stride: 1, ..CloudParams::default() });
        let c = b.from_depth(&cam, &view, &[], &[]);
        assert!(!c.cells.is_empty());
        for cell in &c.cells {
            assert!((cell.x - 2.0).abs() < 0.06, "cell at x {}", cell.x);
        }
        assert!(c.cells.iter().any(|c| c.blocking >= 2));
    }

    #[test]
    fn a_person_box_marks_the_person_not_the_wall_behind() {
        // Camera 0.5 m up looking level at a wall 4 m ahead; a person 0.4 m
        // wide, 2 m ahead, fills columns 27–36 from the floor up to 1.7 m.
        let cam = Camera {
            width: 64,
            height: 48,
            intrinsics: Intrinsics { fx: 40.0, fy: 40.0, cx: 31.5, cy: 23.5 },
            mount: Mount { translation: Vector3::new(0.0, 0.0, 0.5), ..Mount::default() },
            depth_min_m: 0.3,
            depth_max_m: 10.0,
        };
        let mut depth = vec![4.0; 64 * 48];
        for v in 0..48 {
            for u in 27..=36 {
                depth[v * 64 + u] = 2.0;
            }
        }
        let bytes = encode_depth_mm(&depth);
        let view = DepthView::new(64, 48, &bytes).unwrap();
        let mut b = CloudBuilder::new(CloudParams { stride: 1, ..CloudParams::default() });
        // The detector's box is loose: it takes in wall on both sides.
        let person = PixelBox { x_min: 22.0, y_min: 0.0, x_max: 41.0, y_max: 47.0 };
        let c = b.from_depth(&cam, &view, &[person], &[]);
        let marked: Vec<&Cell> = c.cells.iter().filter(|c| c.person == 1).collect();
        assert!(!marked.is_empty());
        assert!(marked.iter().all(|c| (c.x - 2.0).abs() < 0.1), "only the person's cells: {marked:?}");
        assert!(c.cells.iter().any(|c| c.person == 0 && (c.x - 4.0).abs() < 0.1), "the wall is no person");
        let at = c.people[0].expect("the person stands somewhere");
        assert!((at.x - 2.0).abs() < 0.05 && at.y.abs() < 0.05, "stands at {at:?}");
        // No boxes, no people.
        let c = b.from_depth(&cam, &view, &[], &[]);
        assert!(c.people.is_empty() && c.cells.iter().all(|c| c.person == 0));
    }

    #[test]
    fn every_bearing_in_a_coarse_image_is_seen() {
        // The evaluation's 160×120 D455 (fx 85.8) at the default stride (4
        // at 640 pixels): every 4th column would lie 2.7° apart and leave most
        // 1° bins without one; every column lies 0.67° apart. A wall 3 m
        // ahead fills the view; a post 1.5 m ahead covers 10°–20°.
        let (w, h, fx) = (160usize, 120usize, 85.8);
        let cam = Camera {
            width: w as u32,
            height: h as u32,
            intrinsics: Intrinsics { fx, fy: fx, cx: 79.5, cy: 59.5 },
            mount: Mount { translation: Vector3::new(0.0, 0.0, 0.6), ..Mount::default() },
            depth_min_m: 0.3,
            depth_max_m: 10.0,
        };
        let mut depth = vec![0.0; w * h];
        for v in 0..h {
            for u in 0..w {
                let xn = (u as f64 - 79.5) / fx;
                let bearing = -xn.atan();
                depth[v * w + u] = if (10f64.to_radians()..20f64.to_radians()).contains(&bearing) { 1.5 } else { 3.0 };
            }
        }
        let bytes = encode_depth_mm(&depth);
        let view = DepthView::new(w as u32, h as u32, &bytes).unwrap();
        let mut b = CloudBuilder::new(CloudParams::default());
        let seen = b.from_depth(&cam, &view, &[], &[]).seen.expect("built from depth");
        let at = |deg: f64, r: f64| Vector2::new(r * deg.to_radians().cos(), r * deg.to_radians().sin());
        let half_fov = (79.5 / fx).atan().to_degrees();
        let mut deg = -half_fov + 1.0;
        while deg < half_fov - 1.0 {
            // A bin holding the post's edge holds the wall's range too.
            if !(9.0..21.0).contains(&deg) {
                assert!(seen.reaches(&at(deg, 2.5), 0.0), "the wall at {deg:.1}° is seen");
            } else if (10.0..20.0).contains(&deg) {
                assert!(!seen.reaches(&at(deg, 2.5), 0.05), "behind the post at {deg:.1}°");
            }
            assert!(seen.reaches(&at(deg, 1.2), 0.0), "in front of everything at {deg:.1}°");
            deg += 0.25;
        }
        assert_eq!(CloudParams::default().stride_for(160), 1);
        assert_eq!(CloudParams::default().stride_for(640), 4);
        assert_eq!(CloudParams::default().stride_for(1280), 8);
        // Nothing beyond the view is seen.
        assert!(!seen.reaches(&at(half_fov + 3.0, 1.0), 0.0));
        assert!(!seen.reaches(&at(-half_fov - 3.0, 1.0), 0.0));
        // Moving detection sees past a person-sized gap in the middle of the
        // wall's view, within its one-degree outline margin.
        assert!(seen.free_beyond(&at(-20.0, 2.0), 0.2, 2f64.to_radians()));
    }

    #[test]
    fn free_space_ends_at_the_nearest_obstacle_within_the_half_angle() {
        let mut seen = SeenRange::new(Vector2::zeros());
        let at = |deg: f64, r: f64| Vector2::new(r * deg.to_radians().cos(), r * deg.to_radians().sin());
        // The floor seen to 4 m along −5°…+5°; two posts 2 m away at 0.2°–0.8°
        // and 2.2°–2.8°, one 1° bin apart.
        for k in -50..=50 {
            let p = at(f64::from(k) / 10.0, 4.0);
            seen.record(p.x, p.y);
        }
        for deg in [0.2, 0.5, 0.8, 2.2, 2.5, 2.8] {
            let p = at(deg, 2.0);
            seen.record_obstacle(p.x, p.y);
        }
        let deg = 1f64.to_radians();
        assert!(seen.free_beyond(&at(-3.5, 3.0), 0.2, deg), "floor seen to 4 m there");
        assert!(!seen.free_beyond(&at(-3.5, 3.9), 0.2, deg), "not beyond what was measured");
        assert!(!seen.free_beyond(&at(0.5, 3.0), 0.2, 0.0), "behind a post");
        assert!(seen.free_beyond(&at(-0.5, 3.0), 0.2, 0.3 * deg), "beside a post, clear of its outline");
        assert!(!seen.free_beyond(&at(-0.5, 3.0), 0.2, deg), "within a degree of the post's outline");
        assert!(!seen.free_beyond(&at(1.5, 3.0), 0.2, deg), "between the posts, within a degree of both");
        assert!(!seen.free_beyond(&at(-3.5, 3.0), 0.2, 2.0 * deg), "the half angle reaches past the measured floor");
        assert!(!seen.free_beyond(&at(30.0, 1.0), 0.2, deg), "never measured");
    }
}
