//! Fusion of repeated target observations (odom frame).
//!
//! - A fixed target ([`FixedTarget`]): single-frame estimates scatter (the
//!   paper's "golden spheres") and some are plainly wrong (a box bleeding onto
//!   the background, a mis-detection). The last `window` observations are
//!   kept; the fused target is the mean of those within a robust gate of their
//!   component-wise median, the gate being `max(gate_floor_m, gate_k ·
//!   1.4826 · MAD)` of the distances to the median (1.4826·MAD estimates σ
//!   for Gaussian scatter). A new observation outside the gate is reported as
//!   an outlier. Outliers stay in the window, so if the target really is
//!   elsewhere (the first sightings were the wrong ones) the median moves
//!   there once the new position holds the majority.
//! - A moving target ([`MovingTarget`], FOLLOW): a constant-velocity Kalman
//!   filter in the plane (state x, y, vx, vy; white-acceleration process
//!   noise), driven by frame stamps. An observation whose Mahalanobis
//!   distance exceeds the χ²(2) gate is rejected; after `reinit_after`
//!   rejections in a row the filter restarts on the new observation (the
//!   target was lost and found again elsewhere). Height is smoothed
//!   separately.

use std::collections::VecDeque;

use nalgebra::{Matrix2, Matrix4, Vector2, Vector3, Vector4};

/// Tunables of the fixed-target fusion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FixedParams {
    /// Observations kept (most recent).
    pub window: usize,
    /// Gate width in robust standard deviations.
    pub gate_k: f64,
    /// The gate is never narrower than this, m (depth noise at short range is
    /// centimetres; without a floor identical estimates would reject any new one).
    pub gate_floor_m: f64,
    /// Gating starts once this many observations are held.
    pub min_for_gating: usize,
}

impl Default for FixedParams {
    fn default() -> Self {
        Self { window: 30, gate_k: 3.0, gate_floor_m: 0.3, min_for_gating: 3 }
    }
}

/// Tunables of the moving-target filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MovingParams {
    /// Standard deviation of the target's acceleration, m/s² (a walking person ≈ 1).
    pub accel_sigma: f64,
    /// Observation noise σ = base + per_m · range, m.
    pub meas_sigma_base_m: f64,
    pub meas_sigma_per_m: f64,
    /// Initial velocity uncertainty, m/s.
    pub initial_speed_sigma: f64,
    /// χ²(2 dof) gate on the innovation; 13.8 is the 99.9 % quantile.
    pub gate_chi2: f64,
    /// Consecutive rejections after which the filter restarts.
    pub reinit_after: u32,
}

impl Default for MovingParams {
    fn default() -> Self {
        Self {
            accel_sigma: 1.0,
            meas_sigma_base_m: 0.1,
            meas_sigma_per_m: 0.02,
            initial_speed_sigma: 1.5,
            gate_chi2: 13.8,
            reinit_after: 3,
        }
    }
}

/// The state of a track after an update.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fused {
    pub target: Vector3<f64>,
    /// Whether the latest observation was accepted.
    pub accepted: bool,
    pub observations: u32,
    pub rejected: u32,
    /// Fixed: RMS distance of the accepted observations to the fused target.
    /// Moving: 1-σ position uncertainty of the filter, sqrt(P_xx + P_yy).
    pub spread_m: f64,
    pub velocity: Vector2<f64>,
}

fn median(values: &mut [f64]) -> f64 {
    let n = values.len();
    values.sort_unstable_by(f64::total_cmp);
    if n % 2 == 1 { values[n / 2] } else { (values[n / 2 - 1] + values[n / 2]) / 2.0 }
}

/// Robust fusion of estimates of a target that does not move.
#[derive(Clone, Debug)]
pub struct FixedTarget {
    params: FixedParams,
    window: VecDeque<Vector3<f64>>,
    observations: u32,
    rejected: u32,
    last: Option<Fused>,
}

impl FixedTarget {
    pub fn new(params: FixedParams) -> Self {
        Self { params, window: VecDeque::new(), observations: 0, rejected: 0, last: None }
    }

    /// Median, gate and inlier mean of the window.
    fn estimate(&self) -> (Vector3<f64>, f64, Vector3<f64>, f64) {
        let n = self.window.len();
        let mut xs: Vec<f64> = self.window.iter().map(|p| p.x).collect();
        let mut ys: Vec<f64> = self.window.iter().map(|p| p.y).collect();
        let mut zs: Vec<f64> = self.window.iter().map(|p| p.z).collect();
        let m = Vector3::new(median(&mut xs), median(&mut ys), median(&mut zs));
        let mut r: Vec<f64> = self.window.iter().map(|p| (p - m).norm()).collect();
        let mad = median(&mut r);
        let gate = if n < self.params.min_for_gating {
            f64::INFINITY
        } else {
            self.params.gate_floor_m.max(self.params.gate_k * 1.4826 * mad)
        };
        let inliers: Vec<&Vector3<f64>> = self.window.iter().filter(|p| (*p - m).norm() <= gate).collect();
        let mean = inliers.iter().fold(Vector3::zeros(), |a, p| a + *p) / inliers.len() as f64;
        let spread = (inliers.iter().map(|p| (*p - mean).norm_squared()).sum::<f64>() / inliers.len() as f64).sqrt();
        (m, gate, mean, spread)
    }

    /// Adds one observation and returns the fused estimate.
    pub fn add(&mut self, p: Vector3<f64>) -> Fused {
        let accepted = if self.window.len() >= self.params.min_for_gating {
            let (m, gate, _, _) = self.estimate();
            (p - m).norm() <= gate
        } else {
            true
        };
        self.observations += 1;
        if !accepted {
            self.rejected += 1;
        }
        self.window.push_back(p);
        while self.window.len() > self.params.window.max(1) {
            self.window.pop_front();
        }
        let (_, _, mean, spread) = self.estimate();
        let fused = Fused {
            target: mean,
            accepted,
            observations: self.observations,
            rejected: self.rejected,
            spread_m: spread,
            velocity: Vector2::zeros(),
        };
        self.last = Some(fused);
        fused
    }

    /// The current estimate, if any observation was accepted.
    pub fn current(&self) -> Option<Fused> {
        self.last
    }
}

/// Constant-velocity Kalman filter for a target that moves (FOLLOW).
#[derive(Clone, Debug)]
pub struct MovingTarget {
    params: MovingParams,
    state: Option<KalmanState>,
    observations: u32,
    rejected: u32,
    rejected_in_a_row: u32,
}

#[derive(Clone, Copy, Debug)]
struct KalmanState {
    x: Vector4<f64>,
    p: Matrix4<f64>,
    stamp: f64,
    z: f64,
}

impl KalmanState {
    /// Prediction to `stamp` (no prediction backwards: out-of-order frames
    /// are applied at the filter's own time).
    fn predicted(&self, stamp: f64, accel_sigma: f64) -> KalmanState {
        let dt = (stamp - self.stamp).max(0.0);
        if dt == 0.0 {
            return *self;
        }
        let f = Matrix4::new(
            1.0, 0.0, dt, 0.0, //
            0.0, 1.0, 0.0, dt, //
            0.0, 0.0, 1.0, 0.0, //
            0.0, 0.0, 0.0, 1.0,
        );
        let q2 = accel_sigma * accel_sigma;
        let (a, b, c) = (dt.powi(4) / 4.0 * q2, dt.powi(3) / 2.0 * q2, dt * dt * q2);
        let q = Matrix4::new(
            a, 0.0, b, 0.0, //
            0.0, a, 0.0, b, //
            b, 0.0, c, 0.0, //
            0.0, b, 0.0, c,
        );
        KalmanState { x: f * self.x, p: f * self.p * f.transpose() + q, stamp, z: self.z }
    }

    fn spread(&self) -> f64 {
        (self.p[(0, 0)] + self.p[(1, 1)]).max(0.0).sqrt()
    }
}

impl MovingTarget {
    pub fn new(params: MovingParams) -> Self {
        Self { params, state: None, observations: 0, rejected: 0, rejected_in_a_row: 0 }
    }

    fn init(&self, p: &Vector3<f64>, stamp: f64, sigma: f64) -> KalmanState {
        let v2 = self.params.initial_speed_sigma.powi(2);
        KalmanState {
            x: Vector4::new(p.x, p.y, 0.0, 0.0),
            p: Matrix4::from_diagonal(&Vector4::new(sigma * sigma, sigma * sigma, v2, v2)),
            stamp,
            z: p.z,
        }
    }

    fn fused(&self, s: &KalmanState, accepted: bool) -> Fused {
        Fused {
            target: Vector3::new(s.x[0], s.x[1], s.z),
            accepted,
            observations: self.observations,
            rejected: self.rejected,
            spread_m: s.spread(),
            velocity: Vector2::new(s.x[2], s.x[3]),
        }
    }

    /// Adds an observation made at `stamp` (s) from `range_m` away.
    pub fn add(&mut self, p: Vector3<f64>, stamp: f64, range_m: f64) -> Fused {
        self.observations += 1;
        let sigma = self.params.meas_sigma_base_m + self.params.meas_sigma_per_m * range_m.max(0.0);
        let Some(prev) = self.state else {
            let s = self.init(&p, stamp, sigma);
            self.state = Some(s);
            return self.fused(&s, true);
        };
        let s = prev.predicted(stamp, self.params.accel_sigma);
        let r = Matrix2::from_diagonal_element(sigma * sigma);
        let hp = s.p.fixed_view::<2, 4>(0, 0).into_owned();
        let innovation_cov = hp.fixed_view::<2, 2>(0, 0).into_owned() + r;
        let y = Vector2::new(p.x - s.x[0], p.y - s.x[1]);
        let s_inv = innovation_cov.try_inverse().unwrap_or_else(Matrix2::identity);
        let d2 = (y.transpose() * s_inv * y)[(0, 0)];
        if d2 > self.params.gate_chi2 {
            self.rejected_in_a_row += 1;
            if self.rejected_in_a_row >= self.params.reinit_after {
                self.rejected_in_a_row = 0;
                let s = self.init(&p, stamp, sigma);
                self.state = Some(s);
                return self.fused(&s, true);
            }
            self.rejected += 1;
            self.state = Some(s);
            return self.fused(&s, false);
        }
        self.rejected_in_a_row = 0;
        let k = hp.transpose() * s_inv; // 4×2 gain: P Hᵀ S⁻¹
        let x = s.x + k * y;
        let p_new = (Matrix4::identity() - k * Matrix4::identity().fixed_view::<2, 4>(0, 0)) * s.p;
        let p_new = (p_new + p_new.transpose()) / 2.0;
        let z = s.z + 0.3 * (p.z - s.z);
        let s = KalmanState { x, p: p_new, stamp: s.stamp, z };
        self.state = Some(s);
        self.fused(&s, true)
    }

    /// The estimate predicted to `stamp`, without an observation.
    pub fn current(&self, stamp: f64) -> Option<Fused> {
        self.state.map(|s| self.fused(&s.predicted(stamp, self.params.accel_sigma), true))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn fixed_target_converges_and_rejects_outliers() {
        let truth = Vector3::new(4.0, -1.0, 0.4);
        let noise = Normal::new(0.0, 0.08).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut f = FixedTarget::new(FixedParams::default());
        let mut outliers_sent = 0;
        let mut last = None;
        for i in 0..40 {
            let p = if i % 5 == 3 {
                outliers_sent += 1;
                // Background bleed: the estimate lands 3–5 m farther away.
                truth + Vector3::new(rng.random_range(3.0..5.0), rng.random_range(-1.0..1.0), 0.0)
            } else {
                truth + Vector3::new(noise.sample(&mut rng), noise.sample(&mut rng), noise.sample(&mut rng))
            };
            let r = f.add(p);
            if i % 5 == 3 {
                assert!(!r.accepted, "outlier {i} accepted");
            }
            last = Some(r);
        }
        let r = last.unwrap();
        assert_eq!(r.observations, 40);
        assert_eq!(r.rejected, outliers_sent);
        // Window 30 inliers at σ 0.08 per axis: the mean is within a few cm.
        assert!((r.target - truth).norm() < 0.06, "{:?}", r.target);
        assert!(r.spread_m > 0.05 && r.spread_m < 0.25, "spread {}", r.spread_m);
    }

    #[test]
    fn fixed_target_recovers_when_first_sightings_were_wrong() {
        let mut f = FixedTarget::new(FixedParams::default());
        for _ in 0..3 {
            f.add(Vector3::new(9.0, 0.0, 0.0));
        }
        let mut r = f.add(Vector3::new(3.0, 0.0, 0.0));
        assert!(!r.accepted);
        for _ in 0..5 {
            r = f.add(Vector3::new(3.0, 0.02, 0.0));
        }
        assert!((r.target - Vector3::new(3.0, 0.02, 0.0)).norm() < 0.01, "{:?}", r.target);
    }

    #[test]
    fn moving_target_velocity_is_estimated_from_stamps() {
        // Target walking at (0.8, 0.3) m/s, observed at 5 fps with 5 cm noise.
        let noise = Normal::new(0.0, 0.05).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut f = MovingTarget::new(MovingParams::default());
        let v = Vector2::new(0.8, 0.3);
        let mut r = None;
        for i in 0..50 {
            let t = 100.0 + i as f64 * 0.2;
            let pos = Vector2::new(2.0, 1.0) + v * (t - 100.0);
            let p = Vector3::new(pos.x + noise.sample(&mut rng), pos.y + noise.sample(&mut rng), 1.0);
            r = Some(f.add(p, t, 3.0));
        }
        let r = r.unwrap();
        assert!((r.velocity - v).norm() < 0.15, "velocity {:?}", r.velocity);
        let t_end = 100.0 + 49.0 * 0.2;
        let truth = Vector2::new(2.0, 1.0) + v * (t_end - 100.0);
        assert!((r.target.xy() - truth).norm() < 0.1, "{:?} vs {truth:?}", r.target);
        // Prediction one second ahead follows the velocity.
        let ahead = f.current(t_end + 1.0).unwrap();
        assert!((ahead.target.xy() - (truth + v)).norm() < 0.25);
        assert!(ahead.spread_m > r.spread_m);
        assert_eq!(r.rejected, 0);
    }

    #[test]
    fn moving_target_rejects_a_jump_then_reinitialises() {
        let mut f = MovingTarget::new(MovingParams::default());
        for i in 0..10 {
            f.add(Vector3::new(2.0, 0.0, 1.0), i as f64 * 0.2, 2.0);
        }
        let r = f.add(Vector3::new(8.0, 5.0, 1.0), 2.0, 2.0);
        assert!(!r.accepted);
        assert!((r.target.xy() - Vector2::new(2.0, 0.0)).norm() < 0.1);
        f.add(Vector3::new(8.0, 5.0, 1.0), 2.2, 2.0);
        let r = f.add(Vector3::new(8.0, 5.0, 1.0), 2.4, 2.0);
        assert!(r.accepted);
        assert!((r.target.xy() - Vector2::new(8.0, 5.0)).norm() < 1e-9);
        assert_eq!(r.rejected, 2);
    }
}
