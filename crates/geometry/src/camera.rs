//! The RGB-D camera model: pinhole back-projection, the fixed optical →
//! body rotation and the camera's mounting pose in `base_link`, and the
//! projector that maps pixels with depth to `base_link` points and back.
//!
//! Conventions. Image coordinates are the pinhole's: pixel `(u, v)` of the
//! depth image is the sample at `(u, v)`, the same system the intrinsics
//! `c_x, c_y` are given in. The optical frame has z forward, x right, y down;
//! the camera body frame (REP-103) has x forward, y left, z up, so
//! `body = (z_opt, −x_opt, −y_opt)`. The mount is the body frame's pose in
//! `base_link`: translation plus roll/pitch/yaw applied as
//! `R = Rz(yaw)·Ry(pitch)·Rx(roll)` (the ROS fixed-axis RPY convention).

use nalgebra::{Matrix3, Rotation3, Vector3};

/// Width of the frames a pixel stride is given for: the D455's 640×480
/// streams (docs/design.md).
pub const STRIDE_REFERENCE_WIDTH: u32 = 640;

/// A stride given for a 640-wide frame (every n-th row and column), for a
/// frame `width` pixels wide: the same angle between sampled pixels, at
/// least every pixel. A 160×120 frame taken every 4th pixel keeps one pixel
/// in 16, its sampled columns 2.7° apart.
pub fn scaled_stride(stride_at_reference: usize, width: u32) -> usize {
    let width = width.max(1) as usize;
    let reference = STRIDE_REFERENCE_WIDTH as usize;
    ((stride_at_reference * width + reference / 2) / reference).max(1)
}

/// Pinhole intrinsics, pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Intrinsics {
    /// The point in the optical frame seen at pixel `(u, v)` at depth `z` (m).
    #[inline]
    pub fn back_project(&self, u: f64, v: f64, z: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z)
    }
}

/// Pose of the camera body frame in `base_link`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mount {
    pub translation: Vector3<f64>,
    pub roll: f64,
    pub pitch: f64,
    pub yaw: f64,
}

impl Default for Mount {
    fn default() -> Self {
        Self { translation: Vector3::zeros(), roll: 0.0, pitch: 0.0, yaw: 0.0 }
    }
}

impl Mount {
    /// Rotation of the body frame in `base_link`, `Rz(yaw)·Ry(pitch)·Rx(roll)`.
    pub fn rotation(&self) -> Rotation3<f64> {
        Rotation3::from_euler_angles(self.roll, self.pitch, self.yaw)
    }

    /// The transform optical frame → `base_link`, ready for many points.
    pub fn optical_to_base(&self) -> OpticalToBase {
        let r = self.rotation();
        // Columns: where the optical x, y, z axes point in base_link.
        let m = r.matrix();
        let ex = -m.column(1).into_owned(); // optical x = body −y
        let ey = -m.column(2).into_owned(); // optical y = body −z
        let ez = m.column(0).into_owned(); // optical z = body x
        OpticalToBase { ex, ey, ez, t: self.translation }
    }
}

/// Optical frame → `base_link` as three axis vectors and a translation.
#[derive(Clone, Copy, Debug)]
pub struct OpticalToBase {
    ex: Vector3<f64>,
    ey: Vector3<f64>,
    ez: Vector3<f64>,
    t: Vector3<f64>,
}

impl OpticalToBase {
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.t + self.ex * p.x + self.ey * p.y + self.ez * p.z
    }
}

/// Everything needed to interpret one depth frame on its own.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub intrinsics: Intrinsics,
    pub mount: Mount,
    /// Readings outside `(depth_min_m, depth_max_m)` are invalid
    /// ([`Projector::valid_depth`] includes the bounds and reads one ≤ 0 as unset).
    pub depth_min_m: f64,
    pub depth_max_m: f64,
}

impl Camera {
    /// The `base_link` point seen at pixel `(u, v)` at depth `z`.
    pub fn pixel_to_base(&self, u: f64, v: f64, z: f64) -> Vector3<f64> {
        self.mount.optical_to_base().apply(&self.intrinsics.back_project(u, v, z))
    }

    pub fn depth_is_valid(&self, z_m: f64) -> bool {
        z_m > self.depth_min_m && z_m < self.depth_max_m
    }
}

/// Maps (pixel, depth) to `base_link` and back, with the base_link ← optical
/// rotation and the translation precomputed for many pixels.
///
/// Its depth check is [`Projector::valid_depth`]: inclusive bounds, and a
/// bound ≤ 0 is not enforced (unlike [`Camera::depth_is_valid`], which
/// expects both bounds set and excludes them).
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
        let body_in_base = m.rotation().into_inner();
        // Columns: optical x, y, z axes expressed in the body frame.
        let optical_in_body = Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
        Self {
            intrinsics: camera.intrinsics,
            rotation: body_in_base * optical_in_body,
            translation: m.translation,
            depth_min_m: camera.depth_min_m,
            depth_max_m: camera.depth_max_m,
        }
    }

    /// The depth in metres of a reading in millimetres, if it is a usable
    /// return: not 0 and within the camera's range (a bound ≤ 0 is not enforced).
    #[inline]
    pub fn valid_depth(&self, depth_mm: u16) -> Option<f64> {
        if depth_mm == 0 {
            return None;
        }
        let d = depth_mm as f64 * 1e-3;
        let ok =
            (self.depth_min_m <= 0.0 || d >= self.depth_min_m) && (self.depth_max_m <= 0.0 || d <= self.depth_max_m);
        ok.then_some(d)
    }

    /// The `base_link` point seen at pixel `(u, v)` (pixel centres at integers) at depth `d` metres.
    #[inline]
    pub fn project(&self, u: f64, v: f64, d: f64) -> Vector3<f64> {
        self.rotation * self.intrinsics.back_project(u, v, d) + self.translation
    }

    /// Where the ray through pixel `(u, v)` meets the ground (`base_link`
    /// z = 0), if it points below the horizon: the footprint of an object
    /// standing on the floor, from the bottom of its box, without depth.
    pub fn ground_point(&self, u: f64, v: f64) -> Option<Vector3<f64>> {
        let ray = self.rotation * self.intrinsics.back_project(u, v, 1.0);
        (ray.z < -1e-9).then(|| self.translation + ray * (-self.translation.z / ray.z))
    }

    /// The pixel `(u, v)` and depth at which a `base_link` point is seen, if in front of the camera.
    #[inline]
    pub fn pixel_of(&self, p: Vector3<f64>) -> Option<(f64, f64, f64)> {
        let optical = self.rotation.transpose() * (p - self.translation);
        (optical.z > 0.0).then(|| {
            let k = &self.intrinsics;
            (k.fx * optical.x / optical.z + k.cx, k.fy * optical.y / optical.z + k.cy, optical.z)
        })
    }
}
/// An image box in pixel coordinates (`x_min ≤ u < x_max`, `y_min ≤ v < y_max`):
/// a detector's box as the subgoal estimator and the local planner read it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelBox {
    pub x_min: f64,
    pub y_min: f64,
    pub x_max: f64,
    pub y_max: f64,
}

impl PixelBox {
    pub fn centre(&self) -> (f64, f64) {
        ((self.x_min + self.x_max) / 2.0, (self.y_min + self.y_max) / 2.0)
    }

    /// The box shrunk about its centre to `fraction` of its width and height.
    pub fn central(&self, fraction: f64) -> PixelBox {
        let (uc, vc) = self.centre();
        let hw = (self.x_max - self.x_min) * fraction / 2.0;
        let hh = (self.y_max - self.y_min) * fraction / 2.0;
        PixelBox { x_min: uc - hw, y_min: vc - hh, x_max: uc + hw, y_max: vc + hh }
    }

    /// Whether the pixel (u, v) lies in the box.
    pub fn contains(&self, u: f64, v: f64) -> bool {
        u >= self.x_min && u < self.x_max && v >= self.y_min && v < self.y_max
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    fn close(a: &Vector3<f64>, b: [f64; 3]) {
        assert!((a - Vector3::from(b)).norm() < 1e-9, "{a:?} != {b:?}");
    }

    #[test]
    fn a_ray_below_the_horizon_meets_the_ground_where_the_point_projects() {
        let camera = Camera {
            width: 160,
            height: 120,
            intrinsics: Intrinsics { fx: 80.0, fy: 80.0, cx: 80.0, cy: 60.0 },
            mount: Mount { translation: Vector3::new(0.3, 0.0, 0.5), ..Mount::default() },
            depth_min_m: 0.0,
            depth_max_m: 1e3,
        };
        let p = Projector::new(&camera);
        // 20 px below the centre at fx 80: 0.5 m down over 2 m ahead.
        close(&p.ground_point(80.0, 80.0).unwrap(), [2.3, 0.0, 0.0]);
        let far_left = Vector3::new(4.0, 1.5, 0.0);
        let (u, v, _) = p.pixel_of(far_left).unwrap();
        close(&p.ground_point(u, v).unwrap(), [4.0, 1.5, 0.0]);
        // The horizon and above: no ground.
        assert!(p.ground_point(80.0, 60.0).is_none());
        assert!(p.ground_point(80.0, 10.0).is_none());
    }

    #[test]
    fn back_projection_follows_the_pinhole_formula() {
        let k = Intrinsics { fx: 400.0, fy: 500.0, cx: 320.0, cy: 240.0 };
        // X = (u − cx)Z/fx, Y = (v − cy)Z/fy.
        close(&k.back_project(420.0, 140.0, 2.0), [0.5, -0.4, 2.0]);
        close(&k.back_project(320.0, 240.0, 3.0), [0.0, 0.0, 3.0]);
    }

    #[test]
    fn a_level_forward_camera_maps_optical_to_rep103() {
        let m = Mount { translation: Vector3::new(0.3, 0.0, 0.5), ..Mount::default() };
        let t = m.optical_to_base();
        // Optical z (forward) → base x; optical x (right) → base −y; optical y (down) → base −z.
        close(&t.apply(&Vector3::new(0.0, 0.0, 2.0)), [2.3, 0.0, 0.5]);
        close(&t.apply(&Vector3::new(1.0, 0.0, 0.0)), [0.3, -1.0, 0.5]);
        close(&t.apply(&Vector3::new(0.0, 1.0, 0.0)), [0.3, 0.0, -0.5]);
    }

    #[test]
    fn mount_yaw_and_pitch_rotate_the_view() {
        // Camera turned 90° left: looking along base +y.
        let m = Mount { yaw: FRAC_PI_2, ..Mount::default() };
        close(&m.optical_to_base().apply(&Vector3::new(0.0, 0.0, 2.0)), [0.0, 2.0, 0.0]);
        // Optical x (right of the image) now points along base +x.
        close(&m.optical_to_base().apply(&Vector3::new(1.0, 0.0, 0.0)), [1.0, 0.0, 0.0]);
        // Pitched down 30° (positive pitch about y tips x toward −z).
        let p = 30f64.to_radians();
        let m = Mount { pitch: p, ..Mount::default() };
        close(&m.optical_to_base().apply(&Vector3::new(0.0, 0.0, 1.0)), [p.cos(), 0.0, -p.sin()]);
        // Rolled 90° about x: optical x (right) → body −y → base −z.
        let m = Mount { roll: FRAC_PI_2, ..Mount::default() };
        close(&m.optical_to_base().apply(&Vector3::new(1.0, 0.0, 0.0)), [0.0, 0.0, -1.0]);
    }

    fn pitched(pitch: f64) -> Camera {
        Camera {
            width: 640,
            height: 480,
            intrinsics: Intrinsics { fx: 400.0, fy: 400.0, cx: 320.0, cy: 240.0 },
            mount: Mount { translation: Vector3::new(0.2, 0.0, 0.5), roll: 0.0, pitch, yaw: 0.0 },
            depth_min_m: 0.3,
            depth_max_m: 10.0,
        }
    }

    #[test]
    fn the_optical_axis_of_a_level_camera_looks_forward() {
        let p = Projector::new(&pitched(0.0));
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
        let p = Projector::new(&pitched(pitch));
        let d = 0.5 / pitch.sin();
        let x = p.project(320.0, 240.0, d);
        assert!(x.z.abs() < 1e-9, "{x}");
        assert!((x.x - (0.2 + d * pitch.cos())).abs() < 1e-9);
    }

    #[test]
    fn projection_and_pixel_lookup_are_inverse() {
        let p = Projector::new(&pitched(0.3));
        let point = p.project(101.0, 377.0, 3.3);
        let (u, v, d) = p.pixel_of(point).unwrap();
        assert!((u - 101.0).abs() < 1e-9 && (v - 377.0).abs() < 1e-9 && (d - 3.3).abs() < 1e-9);
    }

    #[test]
    fn the_projector_agrees_with_the_camera_model() {
        let cam = Camera { mount: Mount { roll: 0.1, yaw: -0.4, ..pitched(0.3).mount }, ..pitched(0.3) };
        let p = Projector::new(&cam);
        for (u, v, d) in [(0.0, 0.0, 1.0), (101.0, 377.0, 3.3), (639.0, 479.0, 7.5)] {
            assert!((p.project(u, v, d) - cam.pixel_to_base(u, v, d)).norm() < 1e-12);
        }
    }

    #[test]
    fn depth_validity_follows_the_camera_range() {
        let p = Projector::new(&pitched(0.0));
        assert_eq!(p.valid_depth(0), None);
        assert_eq!(p.valid_depth(200), None);
        assert_eq!(p.valid_depth(11_000), None);
        assert_eq!(p.valid_depth(1500), Some(1.5));
        // A bound ≤ 0 is not enforced.
        let open = Projector::new(&Camera { depth_min_m: 0.0, depth_max_m: 0.0, ..pitched(0.0) });
        assert_eq!((open.valid_depth(1), open.valid_depth(65_535)), (Some(0.001), Some(65.535)));
    }
}
