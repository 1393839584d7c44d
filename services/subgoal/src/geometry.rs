//! The subgoal formulas (docs/design.md §3), pure functions on plain types.
//!
//! - Egocentric MOVE: turn by `yaw` relative to the anchor's heading, then
//!   drive `f_dist`: `G = [x_a, y_a] + R(θ_a + yaw)·[f_dist, 0]`, heading
//!   `θ_a + yaw`. `|f_dist| < 0.1 m` is a pure rotation.
//! - Visual target: the median valid depth inside the box, back-projected
//!   through the box centre with the frame's intrinsics, moved to `base_link`
//!   by the camera mount, to `odom` by the frame's odometry pose; the goal
//!   lies `d_s` short of the target along the bearing from the robot.

use nalgebra::{Vector2, Vector3};
use vlnav_geometry::camera::Camera;
use vlnav_geometry::depth::DepthView;
pub(crate) use vlnav_geometry::{GoalSpec, Pose2, wrap_angle};

/// Tunables of the egocentric MOVE (the authors' values by default).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MoveParams {
    /// `|f_dist|` below this is a pure rotation, m.
    pub rotation_only_below_m: f64,
    /// A pure rotation is reached within this heading error, rad.
    pub yaw_tolerance: f64,
    /// Smallest position tolerance; the step's `d_s` raises it, m.
    pub min_position_tolerance: f64,
}

impl Default for MoveParams {
    fn default() -> Self {
        Self { rotation_only_below_m: 0.1, yaw_tolerance: 0.2, min_position_tolerance: 0.25 }
    }
}

/// MOVE relative to `anchor`: turn by `yaw`, then drive `f_dist` metres.
pub fn move_goal(anchor: Pose2, f_dist: f64, yaw: f64, d_s: f64, p: &MoveParams) -> GoalSpec {
    let heading = wrap_angle(anchor.theta + yaw);
    let rotation_only = f_dist.abs() < p.rotation_only_below_m;
    let (s, c) = heading.sin_cos();
    let (dx, dy) = if rotation_only { (0.0, 0.0) } else { (c * f_dist, s * f_dist) };
    GoalSpec {
        pose: Pose2::new(anchor.x + dx, anchor.y + dy, heading),
        position_tolerance: p.min_position_tolerance.max(d_s),
        yaw_tolerance: p.yaw_tolerance,
        rotation_only,
        landmark: None,
    }
}

pub use vlnav_geometry::camera::PixelBox;

/// How the box depth is sampled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxDepthParams {
    /// Fewer valid pixels than this and there is no estimate (authors: 20).
    pub min_valid_pixels: usize,
    /// The median is taken over this central fraction of the box's width and
    /// height first, so background seen around the object's silhouette at the
    /// box edges does not pull it; the whole box is used only when the centre
    /// has too few valid pixels.
    pub central_fraction: f64,
}

impl Default for BoxDepthParams {
    fn default() -> Self {
        Self { min_valid_pixels: 20, central_fraction: 0.5 }
    }
}

/// The median depth of a box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxDepth {
    pub depth_m: f64,
    pub valid_pixels: usize,
    /// Whether the central part sufficed (false: the whole box was used).
    pub central: bool,
}

/// Too few valid depth pixels inside the box.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("no depth: {valid} valid pixels inside the box (depth in ({min_m} m, {max_m} m)), at least {needed} needed")]
pub struct NoDepth {
    pub valid: usize,
    pub needed: usize,
    pub min_m: f64,
    pub max_m: f64,
}

fn valid_depths(depth: &DepthView<'_>, b: &PixelBox, cam: &Camera, out: &mut Vec<u16>) {
    out.clear();
    let u0 = b.x_min.ceil().max(0.0) as usize;
    let v0 = b.y_min.ceil().max(0.0) as usize;
    // Exclusive upper bounds: pixel u is inside when x_min ≤ u < x_max.
    let u1 = (b.x_max.ceil().max(0.0) as usize).min(depth.width());
    let v1 = (b.y_max.ceil().max(0.0) as usize).min(depth.height());
    let lo = cam.depth_min_m * 1000.0;
    let hi = cam.depth_max_m * 1000.0;
    for v in v0..v1 {
        for u in u0..u1 {
            let mm = depth.mm(u, v);
            let z = mm as f64;
            if mm != 0 && z > lo && z < hi {
                out.push(mm);
            }
        }
    }
}

fn median_mm(values: &mut [u16]) -> f64 {
    let n = values.len();
    let (_, hi, _) = values.select_nth_unstable(n / 2);
    let hi = *hi as f64;
    if n % 2 == 1 {
        hi
    } else {
        let lo = *values[..n / 2].iter().max().expect("n ≥ 2") as f64;
        (lo + hi) / 2.0
    }
}

/// `Z = median{D(u,v) : (u,v) ∈ B, Z_min < D < Z_max}`, over the box's centre
/// first (see [`BoxDepthParams::central_fraction`]).
pub fn box_depth(depth: &DepthView<'_>, b: &PixelBox, cam: &Camera, p: &BoxDepthParams) -> Result<BoxDepth, NoDepth> {
    let needed = p.min_valid_pixels.max(1);
    let mut values = Vec::new();
    let mut central = true;
    valid_depths(depth, &b.central(p.central_fraction), cam, &mut values);
    if values.len() < needed {
        central = false;
        valid_depths(depth, b, cam, &mut values);
    }
    if values.len() < needed {
        return Err(NoDepth { valid: values.len(), needed, min_m: cam.depth_min_m, max_m: cam.depth_max_m });
    }
    Ok(BoxDepth { depth_m: median_mm(&mut values) / 1000.0, valid_pixels: values.len(), central })
}

/// The target seen through the box centre at `depth_m`, in `odom`.
pub fn target_in_odom(cam: &Camera, b: &PixelBox, depth_m: f64, robot: &Pose2) -> Vector3<f64> {
    let (uc, vc) = b.centre();
    robot.transform_3d(&cam.pixel_to_base(uc, vc, depth_m))
}

/// The goal `d_s` short of `target` along the bearing from the robot, facing
/// the target: `goal = robot + (d − d_s)(cos θ, sin θ)`; when the robot is
/// already within `d_s` the goal is where it stands.
pub fn approach_goal(robot: &Pose2, target: &Vector2<f64>, d_s: f64) -> Pose2 {
    let delta = target - robot.position();
    let d = delta.norm();
    if d < 1e-9 {
        return *robot;
    }
    let bearing = delta.y.atan2(delta.x);
    let travel = (d - d_s).max(0.0);
    Pose2::new(robot.x + travel * bearing.cos(), robot.y + travel * bearing.sin(), bearing)
}

/// The heading of an approach goal for a fixed target: the bearing of the
/// approach line from `from` (where the robot first observed the target) to
/// `target`; `otherwise` when the line has no length. The goal's position
/// stays where [`approach_goal`] puts it; its heading is the course a relative
/// step after it turns from (“stop before the person, then turn right 45°”),
/// and the line the robot was sent along does not swing with the robot's
/// weave round obstacles on the way (docs/design.md §3).
pub fn approach_heading(from: &Vector2<f64>, target: &Vector2<f64>, otherwise: f64) -> f64 {
    let line = target - from;
    if line.norm() < 1e-9 { otherwise } else { line.y.atan2(line.x) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};
    use vlnav_geometry::camera::{Intrinsics, Mount};
    use vlnav_geometry::depth::encode_depth_mm;

    const EPS: f64 = 1e-9;

    fn near(a: f64, b: f64) {
        assert!((a - b).abs() < EPS, "{a} != {b}");
    }

    #[test]
    fn move_left_turn_4m_from_a_90_degree_heading() {
        // Anchor at (1, 2) facing +y; "left turn, 4 m": heading π, goal 4 m toward −x.
        let g = move_goal(Pose2::new(1.0, 2.0, FRAC_PI_2), 4.0, FRAC_PI_2, 0.0, &MoveParams::default());
        near(g.pose.x, -3.0);
        near(g.pose.y, 2.0);
        near(g.pose.theta, PI);
        assert!(!g.rotation_only);
        near(g.position_tolerance, 0.25);
    }

    #[test]
    fn move_with_negative_yaw_turns_right() {
        // Facing +x, turn right 90° then 2.5 m: goal at (0, −2.5) heading −π/2.
        let g = move_goal(Pose2::new(0.0, 0.0, 0.0), 2.5, -1.57, 1.2, &MoveParams::default());
        near(g.pose.x, 2.5 * (-1.57f64).cos());
        near(g.pose.y, 2.5 * (-1.57f64).sin());
        assert!((g.pose.y + 2.5).abs() < 1e-5);
        near(g.pose.theta, -1.57);
        // Tolerance max(0.25, d_s).
        near(g.position_tolerance, 1.2);
    }

    #[test]
    fn move_heading_wraps_and_backwards_moves_reverse() {
        let g = move_goal(Pose2::new(0.0, 0.0, 3.0), 1.0, 0.5, 0.0, &MoveParams::default());
        near(g.pose.theta, 3.5 - 2.0 * PI);
        near(g.pose.x, 3.5f64.cos());
        near(g.pose.y, 3.5f64.sin());
        let g = move_goal(Pose2::new(1.0, 1.0, 0.0), -2.0, 0.0, 0.0, &MoveParams::default());
        near(g.pose.x, -1.0);
        near(g.pose.y, 1.0);
    }

    #[test]
    fn small_move_is_a_pure_rotation_with_yaw_tolerance() {
        let g = move_goal(Pose2::new(3.0, -1.0, 0.2), 0.05, -1.0, 0.0, &MoveParams::default());
        assert!(g.rotation_only);
        near(g.pose.x, 3.0);
        near(g.pose.y, -1.0);
        near(g.pose.theta, -0.8);
        near(g.yaw_tolerance, 0.2);
    }

    fn camera() -> Camera {
        Camera {
            width: 640,
            height: 480,
            intrinsics: Intrinsics { fx: 388.6187, fy: 388.6187, cx: 320.6609, cy: 239.7847 },
            mount: Mount::default(),
            depth_min_m: 0.5,
            depth_max_m: 10.0,
        }
    }

    fn filled(cam: &Camera, f: impl Fn(usize, usize) -> f64) -> Vec<u8> {
        let (w, h) = (cam.width as usize, cam.height as usize);
        let d: Vec<f64> = (0..w * h).map(|i| f(i % w, i / w)).collect();
        encode_depth_mm(&d)
    }

    #[test]
    fn box_depth_is_the_median_of_valid_central_pixels() {
        let cam = camera();
        // Object at 3 m in the box's centre, background at 8 m around it, a
        // few invalid and too-close pixels inside.
        let bytes = filled(&cam, |u, v| {
            if (300..340).contains(&u) && (200..280).contains(&v) {
                if u == 320 {
                    0.0
                } else if u == 321 {
                    0.3
                } else {
                    3.0 + 0.001 * ((u + v) % 3) as f64
                }
            } else {
                8.0
            }
        });
        let depth = DepthView::new(640, 480, &bytes).unwrap();
        // The box is twice as wide as the object: the full-box median would be 8 m.
        let b = PixelBox { x_min: 280.0, y_min: 180.0, x_max: 360.0, y_max: 300.0 };
        let r = box_depth(&depth, &b, &cam, &BoxDepthParams::default()).unwrap();
        assert!(r.central);
        assert!((r.depth_m - 3.001).abs() < 0.0015, "{r:?}");
        // Central 50 %: u 300..340 (40 columns) minus the two masked columns, v 210..270.
        assert_eq!(r.valid_pixels, 38 * 60);
    }

    #[test]
    fn box_with_no_valid_depth_is_a_clear_no_depth() {
        let cam = camera();
        let bytes = filled(&cam, |u, _| if u < 100 { 0.0 } else { 12.0 });
        let depth = DepthView::new(640, 480, &bytes).unwrap();
        let b = PixelBox { x_min: 10.0, y_min: 10.0, x_max: 90.0, y_max: 90.0 };
        let e = box_depth(&depth, &b, &cam, &BoxDepthParams::default()).unwrap_err();
        assert_eq!(e, NoDepth { valid: 0, needed: 20, min_m: 0.5, max_m: 10.0 });
        assert!(e.to_string().contains("0 valid pixels"));
        // Beyond depth_max counts as invalid too.
        let b = PixelBox { x_min: 200.0, y_min: 10.0, x_max: 300.0, y_max: 90.0 };
        assert!(box_depth(&depth, &b, &cam, &BoxDepthParams::default()).is_err());
    }

    #[test]
    fn small_box_falls_back_to_the_whole_box() {
        let cam = camera();
        let bytes = filled(&cam, |_, _| 2.0);
        let depth = DepthView::new(640, 480, &bytes).unwrap();
        // 6 × 6 box: the centre has 9 pixels (< 20), the whole box 36.
        let b = PixelBox { x_min: 100.0, y_min: 100.0, x_max: 106.0, y_max: 106.0 };
        let r = box_depth(&depth, &b, &cam, &BoxDepthParams::default()).unwrap();
        assert!(!r.central);
        assert_eq!(r.valid_pixels, 36);
        near(r.depth_m, 2.0);
    }

    #[test]
    fn even_count_median_averages_the_middle_pair() {
        near(median_mm(&mut [4000, 1000, 3000, 2000]), 2500.0);
        near(median_mm(&mut [7]), 7.0);
    }

    #[test]
    fn target_straight_ahead_and_off_centre_match_the_spec_formula() {
        let cam = camera();
        let k = cam.intrinsics;
        let robot = Pose2::new(0.0, 0.0, 0.0);
        // Box centred on the principal point at 4 m: 4 m ahead.
        let b = PixelBox { x_min: k.cx - 10.0, y_min: k.cy - 10.0, x_max: k.cx + 10.0, y_max: k.cy + 10.0 };
        let t = target_in_odom(&cam, &b, 4.0, &robot);
        assert!((t - Vector3::new(4.0, 0.0, 0.0)).norm() < 1e-9);
        // Box right of centre: X_c = (u_c − c_x)Z/f_x, base Y = −X_c.
        let b = PixelBox { x_min: 400.0, y_min: 230.0, x_max: 420.0, y_max: 250.0 };
        let t = target_in_odom(&cam, &b, 2.0, &robot);
        let xc = (410.0 - k.cx) * 2.0 / k.fx;
        let yc = (240.0 - k.cy) * 2.0 / k.fy;
        assert!((t - Vector3::new(2.0, -xc, -yc)).norm() < 1e-9);
    }

    #[test]
    fn target_uses_mount_and_a_90_degree_robot_heading() {
        let mut cam = camera();
        cam.mount = Mount { translation: Vector3::new(0.3, 0.1, 0.5), ..Mount::default() };
        let k = cam.intrinsics;
        // Robot at (2, 1) facing +y (90°); target 3 m straight ahead of the camera.
        let robot = Pose2::new(2.0, 1.0, FRAC_PI_2);
        let b = PixelBox { x_min: k.cx - 5.0, y_min: k.cy - 5.0, x_max: k.cx + 5.0, y_max: k.cy + 5.0 };
        let t = target_in_odom(&cam, &b, 3.0, &robot);
        // base (3.3, 0.1, 0.5) → odom (2 − 0.1, 1 + 3.3, 0.5).
        assert!((t - Vector3::new(1.9, 4.3, 0.5)).norm() < 1e-9, "{t:?}");
        // Goal 1 m short along the bearing.
        let g = approach_goal(&robot, &Vector2::new(t.x, t.y), 1.0);
        let d = ((0.1f64).powi(2) + 3.3f64.powi(2)).sqrt();
        let bearing = (3.3f64).atan2(-0.1);
        near(g.theta, bearing);
        near(g.x, 2.0 + (d - 1.0) * bearing.cos());
        near(g.y, 1.0 + (d - 1.0) * bearing.sin());
    }

    #[test]
    fn target_behind_the_robot_gives_a_goal_behind_facing_it() {
        // Robot at origin facing +x, target at (−3, 0) (e.g. from an earlier frame).
        let robot = Pose2::new(0.0, 0.0, 0.0);
        let g = approach_goal(&robot, &Vector2::new(-3.0, 0.0), 1.0);
        near(g.x, -2.0);
        near(g.y, 0.0);
        near(g.theta.abs(), PI);
        // A camera looking backwards (mount yaw π) sees it in front of its lens.
        let mut cam = camera();
        cam.mount = Mount { yaw: PI, ..Mount::default() };
        let k = cam.intrinsics;
        let b = PixelBox { x_min: k.cx - 5.0, y_min: k.cy - 5.0, x_max: k.cx + 5.0, y_max: k.cy + 5.0 };
        let t = target_in_odom(&cam, &b, 3.0, &robot);
        assert!((t - Vector3::new(-3.0, 0.0, 0.0)).norm() < 1e-9, "{t:?}");
    }

    #[test]
    fn the_approach_heading_is_the_bearing_of_the_line_from_first_sight() {
        near(approach_heading(&Vector2::new(0.0, 0.0), &Vector2::new(4.0, 3.0), 1.0), 3.0f64.atan2(4.0));
        // A line of no length keeps the fallback.
        near(approach_heading(&Vector2::new(4.0, 3.0), &Vector2::new(4.0, 3.0), 0.7), 0.7);
    }

    #[test]
    fn target_within_stopping_distance_keeps_the_robot_in_place_facing_it() {
        let robot = Pose2::new(1.0, 1.0, 0.0);
        let g = approach_goal(&robot, &Vector2::new(1.0, 1.8), 1.5);
        near(g.x, 1.0);
        near(g.y, 1.0);
        near(g.theta, FRAC_PI_2);
    }
}
