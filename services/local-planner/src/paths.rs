//! The motion-primitive library, generated in code from the CMU recipe
//! (`path_generator.m`, docs/design.md §4).
//!
//! Paths are polar curves: at radius `r` from the robot a path lies at angle
//! `shift(r)`, a not-a-knot cubic spline through the waypoints
//! `(0, 0), (1, s1), (2, s2), (2.999, s3), (3, s3)` (degrees), sampled every
//! 0.01 m of radius from 0 to 3 m. The first-level headings `s1` are −27°…27°
//! in 9° steps (one group each); `s2 = s1 + k·9°·0.65` and
//! `s3 = s2 + l·9°·0.65²` for `k, l ∈ −3…3`: 7 × 7 × 7 = 343 paths, 49 per
//! group. Path `id = 49·group + 7·(k + 3) + (l + 3)`, so the mirror image of
//! path `id` (y → −y) is path `342 − id`.

use nalgebra::{DMatrix, DVector};

pub const GROUPS: usize = 7;
pub const PATHS_PER_GROUP: usize = 49;
pub const PATH_COUNT: usize = GROUPS * PATHS_PER_GROUP;
/// Radius reached by every path, m (library units, before scaling).
pub const PATH_RADIUS: f64 = 3.0;
/// Sample spacing in radius, m.
pub const SAMPLE_STEP: f64 = 0.01;
/// Samples per path (r = 0, 0.01, …, 3.0).
pub const SAMPLES: usize = 301;

const ANGLE_DEG: f64 = 27.0;
const DELTA_DEG: f64 = ANGLE_DEG / 3.0;
const LEVEL_SCALE: f64 = 0.65;

/// One primitive: its samples in the library frame (x forward, y left).
#[derive(Clone, Debug)]
pub struct Path {
    pub id: usize,
    pub group: usize,
    /// Waypoint angles (s1, s2, s3), degrees.
    pub shifts_deg: [f64; 3],
    /// `SAMPLES` points; point `k` lies at radius `k · SAMPLE_STEP`.
    pub points: Vec<[f64; 2]>,
}

impl Path {
    /// Arc length of the sampled polyline, m.
    pub fn length(&self) -> f64 {
        self.points.windows(2).map(|w| ((w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2)).sqrt()).sum()
    }

    /// Index of the sample at radius `r` (clamped to the path).
    pub fn index_at_radius(r: f64) -> usize {
        ((r / SAMPLE_STEP).floor().max(0.0) as usize).min(SAMPLES - 1)
    }

    /// Heading of the path's tangent at sample `k`, rad.
    pub fn tangent(&self, k: usize) -> f64 {
        let k = k.clamp(1, SAMPLES - 1);
        let (a, b) = (self.points[k - 1], self.points[k]);
        (b[1] - a[1]).atan2(b[0] - a[0])
    }
}

/// The 343 primitives.
#[derive(Clone, Debug)]
pub struct PathLibrary {
    pub paths: Vec<Path>,
}

impl PathLibrary {
    /// Generates the library (a few hundred small spline solves).
    pub fn generate() -> Self {
        let mut paths = Vec::with_capacity(PATH_COUNT);
        for group in 0..GROUPS {
            let s1 = -ANGLE_DEG + DELTA_DEG * group as f64;
            for k in 0..7 {
                let s2 = s1 + (k as f64 - 3.0) * DELTA_DEG * LEVEL_SCALE;
                for l in 0..7 {
                    let s3 = s2 + (l as f64 - 3.0) * DELTA_DEG * LEVEL_SCALE * LEVEL_SCALE;
                    let spline = NotAKnotSpline::new(&[0.0, 1.0, 2.0, 2.999, 3.0], &[0.0, s1, s2, s3, s3]);
                    let points = (0..SAMPLES)
                        .map(|i| {
                            let r = i as f64 * SAMPLE_STEP;
                            let a = spline.eval(r).to_radians();
                            [r * a.cos(), r * a.sin()]
                        })
                        .collect();
                    paths.push(Path { id: paths.len(), group, shifts_deg: [s1, s2, s3], points });
                }
            }
        }
        Self { paths }
    }

    pub fn len(&self) -> usize {
        self.paths.len()
    }

    pub fn is_empty(&self) -> bool {
        self.paths.is_empty()
    }
}

/// A cubic spline with not-a-knot end conditions (MATLAB's `spline`).
#[derive(Clone, Debug)]
pub struct NotAKnotSpline {
    x: Vec<f64>,
    y: Vec<f64>,
    /// Second derivatives at the knots.
    m: Vec<f64>,
}

impl NotAKnotSpline {
    /// Needs at least four knots in increasing order.
    pub fn new(x: &[f64], y: &[f64]) -> Self {
        let n = x.len();
        assert!(n >= 4 && y.len() == n, "a not-a-knot spline needs ≥ 4 knots");
        let h: Vec<f64> = x.windows(2).map(|w| w[1] - w[0]).collect();
        let mut a = DMatrix::<f64>::zeros(n, n);
        let mut b = DVector::<f64>::zeros(n);
        // Third derivative continuous across the second and the second-to-last knot.
        a[(0, 0)] = -1.0 / h[0];
        a[(0, 1)] = 1.0 / h[0] + 1.0 / h[1];
        a[(0, 2)] = -1.0 / h[1];
        for i in 1..n - 1 {
            a[(i, i - 1)] = h[i - 1];
            a[(i, i)] = 2.0 * (h[i - 1] + h[i]);
            a[(i, i + 1)] = h[i];
            b[i] = 6.0 * ((y[i + 1] - y[i]) / h[i] - (y[i] - y[i - 1]) / h[i - 1]);
        }
        a[(n - 1, n - 3)] = -1.0 / h[n - 3];
        a[(n - 1, n - 2)] = 1.0 / h[n - 3] + 1.0 / h[n - 2];
        a[(n - 1, n - 1)] = -1.0 / h[n - 2];
        let m = a.lu().solve(&b).expect("not-a-knot system is regular for distinct knots");
        Self { x: x.to_vec(), y: y.to_vec(), m: m.iter().copied().collect() }
    }

    pub fn eval(&self, t: f64) -> f64 {
        let n = self.x.len();
        let i = match self.x[1..n - 1].iter().position(|&k| t < k) {
            Some(p) => p,
            None => n - 2,
        };
        let (x0, x1) = (self.x[i], self.x[i + 1]);
        let h = x1 - x0;
        let (a, b) = (x1 - t, t - x0);
        self.m[i] * a.powi(3) / (6.0 * h)
            + self.m[i + 1] * b.powi(3) / (6.0 * h)
            + (self.y[i] / h - self.m[i] * h / 6.0) * a
            + (self.y[i + 1] / h - self.m[i + 1] * h / 6.0) * b
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spline_reproduces_cubics_and_interpolates_knots() {
        // Not-a-knot reproduces any cubic exactly.
        let f = |t: f64| 0.5 * t.powi(3) - 2.0 * t * t + t - 3.0;
        let xs = [0.0, 1.0, 2.0, 2.999, 3.0];
        let ys: Vec<f64> = xs.iter().map(|&t| f(t)).collect();
        let s = NotAKnotSpline::new(&xs, &ys);
        for i in 0..=30 {
            let t = i as f64 * 0.1;
            assert!((s.eval(t) - f(t)).abs() < 1e-6, "t={t}: {} vs {}", s.eval(t), f(t));
        }
        let ys = [0.0, 5.0, -2.0, 7.0, 7.0];
        let s = NotAKnotSpline::new(&xs, &ys);
        for (x, y) in xs.iter().zip(ys) {
            assert!((s.eval(*x) - y).abs() < 1e-9);
        }
    }

    #[test]
    fn library_has_343_paths_in_7_groups_of_49() {
        let lib = PathLibrary::generate();
        assert_eq!(lib.len(), 343);
        for g in 0..GROUPS {
            assert_eq!(lib.paths.iter().filter(|p| p.group == g).count(), 49);
        }
        let firsts: Vec<f64> = (0..GROUPS).map(|g| lib.paths[g * 49].shifts_deg[0]).collect();
        assert_eq!(firsts, vec![-27.0, -18.0, -9.0, 0.0, 9.0, 18.0, 27.0]);
        // Second and third levels: ±27°·0.65 and ±27°·0.65² around the level above.
        let p = &lib.paths[0];
        assert!((p.shifts_deg[1] - (-27.0 - 27.0 * 0.65)).abs() < 1e-12);
        assert!((p.shifts_deg[2] - (p.shifts_deg[1] - 27.0 * 0.65 * 0.65)).abs() < 1e-12);
        assert!(lib.paths.iter().all(|p| p.points.len() == SAMPLES));
    }

    #[test]
    fn every_path_reaches_3m_through_its_waypoints() {
        let lib = PathLibrary::generate();
        for p in &lib.paths {
            let end = p.points[SAMPLES - 1];
            assert!(((end[0].hypot(end[1])) - 3.0).abs() < 1e-12, "path {} ends at {end:?}", p.id);
            let end_angle = end[1].atan2(end[0]).to_degrees();
            assert!((end_angle - p.shifts_deg[2]).abs() < 1e-9);
            for (k, s) in [(100, p.shifts_deg[0]), (200, p.shifts_deg[1])] {
                let q = p.points[k];
                assert!((q[1].atan2(q[0]).to_degrees() - s).abs() < 1e-9);
                assert!((q[0].hypot(q[1]) - k as f64 * 0.01).abs() < 1e-12);
            }
            // 3 m of radius; the curve is a little longer where it bends.
            let len = p.length();
            assert!((3.0..3.5).contains(&len), "path {} length {len}", p.id);
        }
        // The straight path is exactly 3 m long.
        let straight = &lib.paths[3 * 49 + 3 * 7 + 3];
        assert_eq!(straight.shifts_deg, [0.0, 0.0, 0.0]);
        assert!((straight.length() - 3.0).abs() < 1e-9);
        assert!(straight.points.iter().all(|q| q[1].abs() < 1e-12));
    }

    #[test]
    fn library_is_mirror_symmetric() {
        let lib = PathLibrary::generate();
        for p in &lib.paths {
            let m = &lib.paths[PATH_COUNT - 1 - p.id];
            assert_eq!(m.group, GROUPS - 1 - p.group);
            for (a, b) in p.points.iter().zip(&m.points) {
                assert!((a[0] - b[0]).abs() < 1e-9 && (a[1] + b[1]).abs() < 1e-9, "path {} vs {}", p.id, m.id);
            }
        }
    }
}
