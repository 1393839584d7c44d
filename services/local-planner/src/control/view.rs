//! What the camera sees of the plane around the robot ([`View`]): the
//! obstacle memory forgets a cell only where the image shows it.

use nalgebra::Vector2;
use vlnav_geometry::wrap_angle;

/// The camera's view in `base_link`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// Direction of the optical axis, rad (the mount's yaw).
    pub yaw: f64,
    /// Half the horizontal field of view, rad (D455: about 43°).
    pub half_fov: f64,
    /// Where the floor comes into view ahead, m along `base_link`'s x: the
    /// ground under the image's bottom row (a D455 0.6 m up, level: 1.16 m
    /// ahead of the base). Nearer floor is below the image. 0: everywhere.
    pub floor_from_m: f64,
    /// The camera's position in `base_link`: ahead of the base and above
    /// the floor, m. The bottom row's ray falls from there to the floor at
    /// `floor_from_m`, so an obstacle lower than the camera is in the image
    /// only beyond where that ray passes below its top ([`View::top_from`]).
    pub camera_x_m: f64,
    pub camera_z_m: f64,
}

impl View {
    /// The view of a pinhole camera `width` pixels wide with focal length
    /// `fx`, seeing the floor everywhere in its angle.
    pub fn pinhole(width: u32, fx: f64, yaw: f64) -> Self {
        Self { yaw, half_fov: (width as f64 / 2.0 / fx).atan(), floor_from_m: 0.0, camera_x_m: 0.0, camera_z_m: 0.0 }
    }

    /// The view of `camera`, with where its image's bottom row meets the
    /// floor (infinitely far when it never looks down to the floor).
    pub fn of_camera(camera: &vlnav_geometry::camera::Camera) -> Self {
        let projector = vlnav_geometry::camera::Projector::new(camera);
        let bottom = f64::from(camera.height) - 0.5;
        let floor_from_m = projector.ground_point(camera.intrinsics.cx, bottom).map_or(f64::INFINITY, |g| g.x.max(0.0));
        Self {
            floor_from_m,
            camera_x_m: camera.mount.translation.x,
            camera_z_m: camera.mount.translation.z,
            ..Self::pinhole(camera.width, camera.intrinsics.fx, camera.mount.yaw)
        }
    }

    pub(super) fn sees(&self, p: &Vector2<f64>, near: f64) -> bool {
        p.norm() >= near && self.in_angle(p)
    }

    /// Whether `p` (`base_link`) lies within the view's angle, at any range.
    pub(super) fn in_angle(&self, p: &Vector2<f64>) -> bool {
        wrap_angle(p.y.atan2(p.x) - self.yaw).abs() < self.half_fov
    }

    /// Where something `top_m` high (above the floor) comes into the image
    /// ahead, m along x: where the bottom row's ray passes below its top.
    /// The floor itself (0 m): `floor_from_m`; as high as the camera or
    /// higher: the camera's own x. 0 when the image shows the floor everywhere.
    pub fn top_from(&self, top_m: f64) -> f64 {
        if self.floor_from_m <= 0.0 {
            0.0
        } else if top_m >= self.camera_z_m {
            self.camera_x_m.min(self.floor_from_m)
        } else {
            self.camera_x_m + (self.floor_from_m - self.camera_x_m) * (1.0 - top_m.max(0.0) / self.camera_z_m)
        }
    }

    /// Whether something `top_m` high at `p` is in the image: in the view's
    /// angle, and not so near that its top lies below the bottom row.
    pub(super) fn sees_top(&self, p: &Vector2<f64>, near: f64, top_m: f64) -> bool {
        self.sees(p, near) && p.x >= self.top_from(top_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_floor_comes_into_view_where_the_bottom_row_meets_it() {
        use vlnav_geometry::camera::{Camera, Intrinsics, Mount};
        // The simulated D455: 0.6 m up, 0.3 m ahead, level; 480 rows, fy 343.
        let camera = Camera {
            width: 640,
            height: 480,
            intrinsics: Intrinsics { fx: 343.159, fy: 343.159, cx: 320.5, cy: 240.5 },
            mount: Mount { translation: nalgebra::Vector3::new(0.3, 0.0, 0.6), ..Mount::default() },
            depth_min_m: 0.0,
            depth_max_m: 10.0,
        };
        let view = View::of_camera(&camera);
        let expected = 0.3 + 0.6 * 343.159 / (479.5 - 240.5);
        assert!((view.floor_from_m - expected).abs() < 1e-6, "{view:?} vs {expected}");
        assert!((view.half_fov - (320.0f64 / 343.159).atan()).abs() < 1e-12);
    }
}
