//! Planar poses (REP-105: x forward, y left, heading counter-clockwise about
//! z), their composition, and the one angle wrap.

use nalgebra::{Vector2, Vector3};

/// Wraps an angle to (−π, π]; an angle already inside is returned unchanged,
/// bit for bit.
pub fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let a = a % TAU;
    if a > PI {
        a - TAU
    } else if a <= -PI {
        a + TAU
    } else {
        a
    }
}

/// A planar pose: position in metres and heading in radians, of a child
/// frame in its parent (`base_link` in `odom`, a robot in the world).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Pose2 {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

impl Pose2 {
    pub const fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }

    pub fn position(&self) -> Vector2<f64> {
        Vector2::new(self.x, self.y)
    }

    pub fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.theta.is_finite()
    }

    /// A point given in this pose's frame, expressed in the parent frame:
    /// `p' = t + R(θ)·p`.
    pub fn transform(&self, p: &Vector2<f64>) -> Vector2<f64> {
        let (s, c) = self.theta.sin_cos();
        Vector2::new(self.x + c * p.x - s * p.y, self.y + s * p.x + c * p.y)
    }

    /// [`Pose2::transform`] for a 3-D point; z is unchanged.
    pub fn transform_3d(&self, p: &Vector3<f64>) -> Vector3<f64> {
        let q = self.transform(&p.xy());
        Vector3::new(q.x, q.y, p.z)
    }

    /// A point given in the parent frame, expressed in this pose's frame:
    /// `p = R(−θ)·(p' − t)`, the inverse of [`Pose2::transform`].
    pub fn inverse_transform(&self, p: &Vector2<f64>) -> Vector2<f64> {
        let (s, c) = self.theta.sin_cos();
        let d = p - self.position();
        Vector2::new(c * d.x + s * d.y, -s * d.x + c * d.y)
    }

    /// `self ⊕ other`: a pose given in this pose's frame, expressed in the
    /// parent frame.
    pub fn compose(&self, other: &Pose2) -> Pose2 {
        let p = self.transform(&other.position());
        Pose2::new(p.x, p.y, wrap_angle(self.theta + other.theta))
    }

    /// `self⁻¹ ⊕ other`: a pose given in the parent frame, expressed in this
    /// pose's frame (the inverse of [`Pose2::compose`]).
    pub fn relative(&self, other: &Pose2) -> Pose2 {
        let p = self.inverse_transform(&other.position());
        Pose2::new(p.x, p.y, wrap_angle(other.theta - self.theta))
    }

    /// Distance between the two positions, metres.
    pub fn distance(&self, other: &Pose2) -> f64 {
        (self.x - other.x).hypot(self.y - other.y)
    }
}

/// A goal pose in `odom` with its acceptance tolerances.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GoalSpec {
    pub pose: Pose2,
    /// Reached within this distance, m …
    pub position_tolerance: f64,
    /// … and, for a pure rotation, this heading error, rad.
    pub yaw_tolerance: f64,
    pub rotation_only: bool,
    /// For a goal at a fixed landmark's stopping distance: the landmark
    /// (`odom`, on the floor). The distance holds from any bearing.
    pub landmark: Option<Vector2<f64>>,
}

/// A planar body velocity: forward m/s, yaw rate rad/s (counter-clockwise).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Twist {
    pub linear: f64,
    pub angular: f64,
}

impl Twist {
    pub const ZERO: Twist = Twist { linear: 0.0, angular: 0.0 };
    pub const fn new(linear: f64, angular: f64) -> Self {
        Self { linear, angular }
    }
    pub fn is_zero(&self) -> bool {
        self.linear == 0.0 && self.angular == 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    fn near(a: f64, b: f64) {
        assert!((a - b).abs() < 1e-12, "{a} != {b}");
    }

    #[test]
    fn wrap_angle_lands_in_minus_pi_pi() {
        near(wrap_angle(3.0 * PI), PI);
        near(wrap_angle(-PI), PI);
        near(wrap_angle(-1.5 * PI), FRAC_PI_2);
        near(wrap_angle(0.3), 0.3);
        near(wrap_angle(-0.3), -0.3);
        near(wrap_angle(7.0 * PI + 0.25), -PI + 0.25);
    }

    #[test]
    fn wrap_angle_keeps_angles_inside_the_interval_exactly() {
        for a in [-3.1, -1e-300, -0.0, 0.0, 1e-17, 0.5, PI, -PI + 1e-15] {
            assert_eq!(wrap_angle(a).to_bits(), a.to_bits(), "{a}");
        }
    }

    #[test]
    fn transform_follows_rep105() {
        // A frame at (1, 2) facing +y: its x axis is the parent's +y.
        let origin = Pose2::new(1.0, 2.0, FRAC_PI_2);
        let p = origin.transform(&Vector2::new(1.0, 0.0));
        near(p.x, 1.0);
        near(p.y, 3.0);
        let back = origin.inverse_transform(&p);
        near(back.x, 1.0);
        near(back.y, 0.0);
        let q = origin.transform_3d(&Vector3::new(0.0, 1.0, 0.7));
        assert!((q - Vector3::new(0.0, 2.0, 0.7)).norm() < 1e-12, "{q}");
    }

    #[test]
    fn poses_compose_and_invert() {
        let a = Pose2::new(1.0, 2.0, 0.5);
        let b = Pose2::new(-0.3, 0.7, -1.2);
        let c = a.compose(&b);
        let back = a.relative(&c);
        near(back.x, b.x);
        near(back.y, b.y);
        near(back.theta, b.theta);
        // Composition wraps the heading.
        let q = Pose2::new(1.0, 2.0, FRAC_PI_2).compose(&Pose2::new(0.0, 0.0, PI));
        near(q.theta, -FRAC_PI_2);
        near(a.distance(&Pose2::new(4.0, 6.0, 0.0)), 5.0);
    }
}
