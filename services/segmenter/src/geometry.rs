//! Pinhole back-projection into base_link. The mount is the pose of the
//! camera *body* frame (x forward, y left, z up) in base_link; the optical
//! frame (z forward, x right, y down) relates to it by the fixed REP-103
//! rotation: body = (z_opt, −x_opt, −y_opt).

use nalgebra::{Matrix3, Rotation3, Vector3};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mount {
    /// Camera body origin in base_link, metres.
    pub translation: [f64; 3],
    pub roll: f64,
    pub pitch: f64,
    pub yaw: f64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub intrinsics: Intrinsics,
    pub mount: Mount,
    /// Valid depth range, metres (a bound ≤ 0 is not enforced).
    pub depth_min_m: f64,
    pub depth_max_m: f64,
}

/// Maps (pixel, depth) to base_link with the rotation and translation precomputed.
#[derive(Clone, Debug)]
pub struct Projector {
    intrinsics: Intrinsics,
    /// base_link ← optical rotation.
    rotation: Matrix3<f64>,
    translation: Vector3<f64>,
    depth_min_m: f64,
    depth_max_m: f64,
}

impl Projector {
    pub fn new(camera: &Camera) -> Self {
        let m = camera.mount;
        let body_in_base = Rotation3::from_euler_angles(m.roll, m.pitch, m.yaw).into_inner();
        // Columns: optical x, y, z axes expressed in the body frame.
        let optical_in_body = Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
        Self {
            intrinsics: camera.intrinsics,
            rotation: body_in_base * optical_in_body,
            translation: Vector3::from(m.translation),
            depth_min_m: camera.depth_min_m,
            depth_max_m: camera.depth_max_m,
        }
    }

    /// Whether a depth reading in millimetres is a usable return.
    pub fn valid_depth(&self, depth_mm: u16) -> Option<f64> {
        if depth_mm == 0 {
            return None;
        }
        let d = depth_mm as f64 * 1e-3;
        let ok = (self.depth_min_m <= 0.0 || d >= self.depth_min_m) && (self.depth_max_m <= 0.0 || d <= self.depth_max_m);
        ok.then_some(d)
    }

    /// The base_link point seen at pixel (u, v) (pixel centres at integers) at depth `d` metres.
    pub fn project(&self, u: f64, v: f64, d: f64) -> Vector3<f64> {
        let k = &self.intrinsics;
        let optical = Vector3::new((u - k.cx) * d / k.fx, (v - k.cy) * d / k.fy, d);
        self.rotation * optical + self.translation
    }

    /// The pixel (u, v) and depth at which a base_link point is seen, if in front of the camera.
    pub fn pixel_of(&self, p: Vector3<f64>) -> Option<(f64, f64, f64)> {
        let optical = self.rotation.transpose() * (p - self.translation);
        (optical.z > 0.0).then(|| {
            let k = &self.intrinsics;
            (k.fx * optical.x / optical.z + k.cx, k.fy * optical.y / optical.z + k.cy, optical.z)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(pitch: f64) -> Camera {
        Camera {
            width: 640,
            height: 480,
            intrinsics: Intrinsics { fx: 400.0, fy: 400.0, cx: 320.0, cy: 240.0 },
            mount: Mount { translation: [0.2, 0.0, 0.5], roll: 0.0, pitch, yaw: 0.0 },
            depth_min_m: 0.3,
            depth_max_m: 10.0,
        }
    }

    #[test]
    fn the_optical_axis_of_a_level_camera_looks_forward() {
        let p = Projector::new(&camera(0.0));
        let x = p.project(320.0, 240.0, 2.0);
        assert!((x - Vector3::new(2.2, 0.0, 0.5)).norm() < 1e-12, "{x}");
        // A pixel right of centre lies to the right (negative y), one below lies lower.
        assert!(p.project(400.0, 240.0, 2.0).y < 0.0);
        assert!(p.project(320.0, 300.0, 2.0).z < 0.5);
    }

    #[test]
    fn a_camera_pitched_down_sees_the_floor_ahead() {
        // Positive pitch about y tilts the body x axis down (REP-103).
        let pitch = 0.5f64;
        let p = Projector::new(&camera(pitch));
        let d = 0.5 / pitch.sin();
        let x = p.project(320.0, 240.0, d);
        assert!(x.z.abs() < 1e-9, "{x}");
        assert!((x.x - (0.2 + d * pitch.cos())).abs() < 1e-9);
    }

    #[test]
    fn projection_and_pixel_lookup_are_inverse() {
        let p = Projector::new(&camera(0.3));
        let point = p.project(101.0, 377.0, 3.3);
        let (u, v, d) = p.pixel_of(point).unwrap();
        assert!((u - 101.0).abs() < 1e-9 && (v - 377.0).abs() < 1e-9 && (d - 3.3).abs() < 1e-9);
    }

    #[test]
    fn depth_validity_follows_the_camera_range() {
        let p = Projector::new(&camera(0.0));
        assert_eq!(p.valid_depth(0), None);
        assert_eq!(p.valid_depth(200), None);
        assert_eq!(p.valid_depth(11_000), None);
        assert_eq!(p.valid_depth(1500), Some(1.5));
    }
}
