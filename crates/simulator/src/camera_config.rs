//! The camera's settings: the RealSense D455's intrinsics, mount and depth
//! error model. Both the renderer ([`camera`](crate::camera)) and the
//! validated [`World`](crate::World) hold them; this module needs neither.

use crate::geometry::Pose2;

/// Camera settings. Defaults: 640×480 with the paper's Gazebo intrinsics
/// (fx = fy = 343.159, cx = 320.5, cy = 240.5), the camera body 0.30 m ahead of
/// base_link's origin and 0.60 m above it (the front of a Husky's top rail,
/// on a short mast), level and facing forward, and the RealSense D455's
/// depth errors (Intel RealSense D400 series datasheet, rev. 2022, table
/// "D455 depth module": RMS error ≤ 2 % at 4 m, ideal range 0.6–6 m,
/// stereo baseline 95 mm; see docs/perception.md):
/// - noise σ = k·z² with k = 0.005 m⁻¹ (0.08 m = 2 % at 4 m; stereo depth
///   error grows with the square of range);
/// - beyond the reliable range (6 m) a growing share of pixels has no depth
///   (half of them at 10 m), and none beyond `depth_max_m`;
/// - holes at depth discontinuities: background pixels seen by the left
///   (reference) imager but hidden from the right one by a nearer surface
///   have no match; the band left of a near edge is f·B·(1/z_near − 1/z_far)
///   pixels wide.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraConfig {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Camera body position in base_link (x, y, z), metres.
    pub mount: [f64; 3],
    /// Camera yaw in base_link, radians. Roll and pitch are zero (level).
    pub mount_yaw: f64,
    pub depth_min_m: f64,
    pub depth_max_m: f64,
    pub depth_noise_k: f64,
    /// Beyond this range pixels start to lose their depth, metres.
    pub depth_reliable_max_m: f64,
    /// Stereo baseline for the occlusion holes at depth edges, metres (0: none).
    pub stereo_baseline_m: f64,
}

pub const PAPER_WIDTH: u32 = 640;
pub const PAPER_HEIGHT: u32 = 480;
pub const PAPER_F: f64 = 343.159;
pub const PAPER_CX: f64 = 320.5;
pub const PAPER_CY: f64 = 240.5;
pub use vlnav_geometry::depth::D455_NOISE_K;

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            width: PAPER_WIDTH,
            height: PAPER_HEIGHT,
            fx: PAPER_F,
            fy: PAPER_F,
            cx: PAPER_CX,
            cy: PAPER_CY,
            mount: [0.30, 0.0, 0.60],
            mount_yaw: 0.0,
            depth_min_m: 0.3,
            depth_max_m: 10.0,
            depth_noise_k: D455_NOISE_K,
            depth_reliable_max_m: 6.0,
            stereo_baseline_m: 0.095,
        }
    }
}

impl CameraConfig {
    /// The same camera at another resolution: intrinsics scale with it (the
    /// field of view stays the paper's).
    pub fn with_resolution(mut self, width: u32, height: u32) -> Result<Self, String> {
        if !(16..=4096).contains(&width) || !(16..=4096).contains(&height) {
            return Err(format!("resolution {width}×{height} must be within 16…4096 pixels per side"));
        }
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        self.fx *= sx;
        self.cx *= sx;
        self.fy *= sy;
        self.cy *= sy;
        self.width = width;
        self.height = height;
        Ok(self)
    }

    /// Checks the settings; the error names the offending key.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if !(16..=4096).contains(&self.width) {
            return Err(("width", format!("{} must be within 16…4096", self.width)));
        }
        if !(16..=4096).contains(&self.height) {
            return Err(("height", format!("{} must be within 16…4096", self.height)));
        }
        for (k, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !(v.is_finite() && v > 1.0) {
                return Err((k, format!("{v} must be a focal length in pixels > 1")));
            }
        }
        if !self.mount.iter().all(|v| v.is_finite()) || self.mount[2] <= 0.0 || self.mount[2] > 5.0 {
            return Err(("mount", format!("{:?}: the camera must sit above the floor (0 < z ≤ 5 m)", self.mount)));
        }
        if !(self.depth_min_m.is_finite() && self.depth_min_m >= 0.0 && self.depth_min_m < self.depth_max_m) {
            return Err((
                "depth_min_m",
                format!("{} must be ≥ 0 and below depth_max_m ({})", self.depth_min_m, self.depth_max_m),
            ));
        }
        if !(self.depth_max_m.is_finite() && self.depth_max_m <= 65.0) {
            return Err(("depth_max_m", format!("{} must be ≤ 65 m (u16 millimetres)", self.depth_max_m)));
        }
        if !(self.depth_noise_k.is_finite() && (0.0..=0.1).contains(&self.depth_noise_k)) {
            return Err(("depth_noise_k", format!("{} must be within [0, 0.1]", self.depth_noise_k)));
        }
        if !(self.depth_reliable_max_m.is_finite() && self.depth_reliable_max_m > self.depth_min_m) {
            return Err(("depth_reliable_max_m", format!("{} must be above depth_min_m", self.depth_reliable_max_m)));
        }
        if !(self.stereo_baseline_m.is_finite() && (0.0..=1.0).contains(&self.stereo_baseline_m)) {
            return Err(("stereo_baseline_m", format!("{} must be within [0, 1] m", self.stereo_baseline_m)));
        }
        Ok(())
    }

    /// World pose of the camera body for a robot at `robot` (planar part) and its height.
    pub fn pose_in_world(&self, robot: &Pose2) -> (Pose2, f64) {
        let p = robot.compose(&Pose2::new(self.mount[0], self.mount[1], self.mount_yaw));
        (p, self.mount[2])
    }
}
