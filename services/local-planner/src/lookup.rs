//! The voxel → paths lookup table (CMU's `correspondences`), as bit sets.
//!
//! The grid is CMU's trapezoid in library units: 0.02 m voxels, 161 columns
//! in x from 3.2 m down to 0, 451 rows in y whose spacing is scaled by
//! `scaleY(x) = x/3.2 + R/4.5·(3.2 − x)/3.2`, so it is fine near the robot
//! (where paths are close together) and coarse far away; voxel `(i, j)` has
//! its centre at `x = 3.2 − 0.02·i`, `y = scaleY(x)·(4.5 − 0.02·j)`. Each voxel
//! holds the set of paths that pass within the search radius `R` of its
//! centre, as a 343-bit set (six u64 words): a plan cycle ORs sets instead of
//! walking lists, and counting "≥ 2 points" is two ORs per point.
//!
//! Construction stamps each path's tube (radius `R` around every sample)
//! column by column: for a column at `x_c` a sample `(p_x, p_y)` covers
//! `|y − p_y| ≤ sqrt(R² − (x_c − p_x)²)`, the exact set of voxel centres within
//! `R`; chords of consecutive samples are merged before the bits are set. The
//! result equals the brute-force distance check (tested on random voxels)
//! at a small fraction of its cost.

use crate::paths::{PATH_COUNT, PathLibrary};

const WORDS: usize = PATH_COUNT.div_ceil(64);

/// A set of path ids.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PathSet(pub [u64; WORDS]);

impl PathSet {
    pub const EMPTY: PathSet = PathSet([0; WORDS]);

    /// Every path of the library.
    pub fn all() -> Self {
        let mut s = Self::EMPTY;
        for i in 0..PATH_COUNT {
            s.insert(i);
        }
        s
    }

    #[inline]
    pub fn insert(&mut self, i: usize) {
        self.0[i / 64] |= 1 << (i % 64);
    }

    #[inline]
    pub fn contains(&self, i: usize) -> bool {
        self.0[i / 64] & (1 << (i % 64)) != 0
    }

    #[inline]
    pub fn union_with(&mut self, o: &PathSet) {
        for (a, b) in self.0.iter_mut().zip(o.0) {
            *a |= b;
        }
    }

    /// Counts to two: `twice |= once & o; once |= o`.
    #[inline]
    pub fn count_into(once: &mut PathSet, twice: &mut PathSet, o: &PathSet) {
        for w in 0..WORDS {
            twice.0[w] |= once.0[w] & o.0[w];
            once.0[w] |= o.0[w];
        }
    }

    pub fn minus(&self, o: &PathSet) -> PathSet {
        let mut r = *self;
        for (a, b) in r.0.iter_mut().zip(o.0) {
            *a &= !b;
        }
        r
    }

    pub fn len(&self) -> usize {
        self.0.iter().map(|w| w.count_ones() as usize).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.0.iter().all(|&w| w == 0)
    }

    pub fn iter(&self) -> impl Iterator<Item = usize> + '_ {
        self.0.iter().enumerate().flat_map(|(wi, &w)| {
            let mut bits = w;
            std::iter::from_fn(move || {
                if bits == 0 {
                    return None;
                }
                let b = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                Some(wi * 64 + b)
            })
        })
    }
}

/// CMU's trapezoidal collision grid (library units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    pub voxel: f64,
    pub offset_x: f64,
    pub offset_y: f64,
    pub num_x: usize,
    pub num_y: usize,
    pub radius: f64,
}

impl Grid {
    /// CMU's grid for search radius `radius`: 0.02 m, 161 × 451, offsets 3.2 / 4.5 m.
    pub fn cmu(radius: f64) -> Self {
        Self { voxel: 0.02, offset_x: 3.2, offset_y: 4.5, num_x: 161, num_y: 451, radius }
    }

    pub fn len(&self) -> usize {
        self.num_x * self.num_y
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    #[inline]
    pub fn scale_y(&self, x: f64) -> f64 {
        x / self.offset_x + self.radius / self.offset_y * (self.offset_x - x) / self.offset_x
    }

    /// Centre of voxel `(i, j)`.
    pub fn centre(&self, i: usize, j: usize) -> (f64, f64) {
        let x = self.offset_x - self.voxel * i as f64;
        (x, self.scale_y(x) * (self.offset_y - self.voxel * j as f64))
    }

    /// The voxel a library-frame point falls in (nearest centre), as CMU indexes it.
    #[inline]
    pub fn index(&self, x: f64, y: f64) -> Option<usize> {
        let fi = (self.offset_x + self.voxel / 2.0 - x) / self.voxel;
        if !(fi >= 0.0 && fi < self.num_x as f64) {
            return None;
        }
        let sy = self.scale_y(x);
        let fj = (self.offset_y + self.voxel / 2.0 - y / sy) / self.voxel;
        if !(fj >= 0.0 && fj < self.num_y as f64) {
            return None;
        }
        Some(fi as usize * self.num_y + fj as usize)
    }
}

/// For every voxel, the paths within the search radius of its centre.
#[derive(Clone, Debug)]
pub struct LookupTable {
    pub grid: Grid,
    sets: Vec<PathSet>,
}

impl LookupTable {
    pub fn build(library: &PathLibrary, grid: Grid) -> Self {
        let mut sets = vec![PathSet::EMPTY; grid.len()];
        let r = grid.radius;
        let r2 = r * r;
        // Per column: the merged index intervals of the current path's tube.
        let mut intervals: Vec<Vec<(i64, i64)>> = vec![Vec::new(); grid.num_x];
        let scale_y: Vec<f64> = (0..grid.num_x).map(|i| grid.scale_y(grid.centre(i, 0).0)).collect();
        for path in &library.paths {
            for col in intervals.iter_mut() {
                col.clear();
            }
            for &[px, py] in &path.points {
                // Columns whose centre lies within R of the sample in x.
                let i_lo = ((grid.offset_x - (px + r)) / grid.voxel).ceil().max(0.0) as i64;
                let i_hi = ((grid.offset_x - (px - r)) / grid.voxel).floor().min(grid.num_x as f64 - 1.0) as i64;
                for i in i_lo..=i_hi {
                    let xc = grid.offset_x - grid.voxel * i as f64;
                    let dx = xc - px;
                    let rest = r2 - dx * dx;
                    if rest < 0.0 {
                        continue;
                    }
                    let dy = rest.sqrt();
                    let sy = scale_y[i as usize];
                    // y = sy·(offset_y − voxel·j) is decreasing in j.
                    let j_lo = ((grid.offset_y - (py + dy) / sy) / grid.voxel).ceil().max(0.0) as i64;
                    let j_hi =
                        ((grid.offset_y - (py - dy) / sy) / grid.voxel).floor().min(grid.num_y as f64 - 1.0) as i64;
                    if j_lo > j_hi {
                        continue;
                    }
                    let col = &mut intervals[i as usize];
                    match col.last_mut() {
                        Some(last) if j_lo <= last.1 + 1 && j_hi >= last.0 - 1 => {
                            last.0 = last.0.min(j_lo);
                            last.1 = last.1.max(j_hi);
                        }
                        _ => col.push((j_lo, j_hi)),
                    }
                }
            }
            for (i, col) in intervals.iter_mut().enumerate() {
                // Chords of a wiggling path can interleave; merge once more so
                // each voxel is stamped once.
                col.sort_unstable();
                let mut merged: Vec<(i64, i64)> = Vec::with_capacity(col.len());
                for &(a, b) in col.iter() {
                    match merged.last_mut() {
                        Some(m) if a <= m.1 + 1 => m.1 = m.1.max(b),
                        _ => merged.push((a, b)),
                    }
                }
                for (a, b) in merged {
                    for j in a..=b {
                        sets[i * grid.num_y + j as usize].insert(path.id);
                    }
                }
            }
        }
        Self { grid, sets }
    }

    /// The paths near library-frame point `(x, y)`; `None` outside the grid.
    #[inline]
    pub fn paths_near(&self, x: f64, y: f64) -> Option<&PathSet> {
        self.grid.index(x, y).map(|i| &self.sets[i])
    }

    pub fn voxel(&self, i: usize, j: usize) -> &PathSet {
        &self.sets[i * self.grid.num_y + j]
    }

    /// Paths listed over all voxels (a size figure).
    pub fn entries(&self) -> usize {
        self.sets.iter().map(PathSet::len).sum()
    }
}

/// Brute force: minimum distance from `(x, y)` to each path's samples.
pub fn brute_force_distances(library: &PathLibrary, x: f64, y: f64) -> Vec<f64> {
    library
        .paths
        .iter()
        .map(|p| p.points.iter().map(|q| (q[0] - x).hypot(q[1] - y)).fold(f64::INFINITY, f64::min))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::sync::OnceLock;

    fn fixture() -> &'static (PathLibrary, LookupTable) {
        static F: OnceLock<(PathLibrary, LookupTable)> = OnceLock::new();
        F.get_or_init(|| {
            let lib = PathLibrary::generate();
            let table = LookupTable::build(&lib, Grid::cmu(0.45));
            (lib, table)
        })
    }

    #[test]
    fn grid_matches_cmu_dimensions() {
        let g = Grid::cmu(0.45);
        assert_eq!(g.len(), 72_611);
        let (x, y) = g.centre(0, 0);
        assert!((x - 3.2).abs() < 1e-12 && (y - 4.5).abs() < 1e-12);
        // At x = 0 the rows span only ±R.
        let (x, y) = g.centre(160, 0);
        assert!(x.abs() < 1e-9 && (y - 0.45).abs() < 1e-9);
        // A voxel centre indexes to itself.
        for (i, j) in [(0, 0), (17, 300), (160, 450), (80, 225)] {
            let (x, y) = g.centre(i, j);
            assert_eq!(g.index(x, y), Some(i * g.num_y + j));
        }
        assert_eq!(g.index(-0.5, 0.0), None);
        assert_eq!(g.index(3.5, 0.0), None);
        assert_eq!(g.index(1.0, 4.0), None);
    }

    #[test]
    fn table_agrees_with_brute_force_on_random_voxels() {
        let (lib, table) = fixture();
        let g = table.grid;
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut checked_inside = 0;
        for _ in 0..400 {
            let (i, j) = (rng.random_range(0..g.num_x), rng.random_range(0..g.num_y));
            let (x, y) = g.centre(i, j);
            let d = brute_force_distances(lib, x, y);
            let set = table.voxel(i, j);
            for (p, &dist) in d.iter().enumerate() {
                // Exactly on the radius either answer is right.
                if (dist - g.radius).abs() < 1e-9 {
                    continue;
                }
                assert_eq!(set.contains(p), dist < g.radius, "voxel ({i}, {j}) path {p}: distance {dist}");
                checked_inside += (dist < g.radius) as usize;
            }
        }
        assert!(checked_inside > 1000, "too few voxels near paths sampled: {checked_inside}");
    }

    #[test]
    fn table_agrees_with_brute_force_near_the_paths() {
        // Random voxels mostly miss the tubes; also check voxels next to paths.
        let (lib, table) = fixture();
        let g = table.grid;
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for _ in 0..300 {
            let p = &lib.paths[rng.random_range(0..lib.len())];
            let q = p.points[rng.random_range(0..p.points.len())];
            let (x, y) = (q[0] + rng.random_range(-0.5..0.5), q[1] + rng.random_range(-0.5..0.5));
            let Some(idx) = g.index(x, y) else { continue };
            let (i, j) = (idx / g.num_y, idx % g.num_y);
            let (cx, cy) = g.centre(i, j);
            let d = brute_force_distances(lib, cx, cy);
            for (pid, &dist) in d.iter().enumerate() {
                if (dist - g.radius).abs() < 1e-9 {
                    continue;
                }
                assert_eq!(table.voxel(i, j).contains(pid), dist < g.radius, "voxel ({i}, {j}) path {pid}: {dist}");
            }
        }
    }

    #[test]
    fn a_point_dead_ahead_hits_the_straight_paths_only() {
        let (_, table) = fixture();
        let set = table.paths_near(2.0, 0.0).unwrap();
        assert!(set.contains(3 * 49 + 24)); // the straight path
        assert!(!set.contains(0) && !set.contains(342)); // the hardest turns
        // Mirror symmetry carries over to the table.
        let left = table.paths_near(1.5, 0.6).unwrap();
        let right = table.paths_near(1.5, -0.6).unwrap();
        let mirrored: Vec<usize> = right.iter().map(|p| 342 - p).collect::<Vec<_>>().into_iter().rev().collect();
        assert_eq!(left.iter().collect::<Vec<_>>(), mirrored);
    }

    #[test]
    fn path_set_counts_to_two() {
        let mut a = PathSet::EMPTY;
        a.insert(3);
        a.insert(300);
        let mut b = PathSet::EMPTY;
        b.insert(300);
        let (mut once, mut twice) = (PathSet::EMPTY, PathSet::EMPTY);
        PathSet::count_into(&mut once, &mut twice, &a);
        PathSet::count_into(&mut once, &mut twice, &b);
        assert_eq!(once.iter().collect::<Vec<_>>(), vec![3, 300]);
        assert_eq!(twice.iter().collect::<Vec<_>>(), vec![300]);
        assert_eq!(PathSet::all().len(), 343);
        assert_eq!(PathSet::all().minus(&a).len(), 341);
    }
}
