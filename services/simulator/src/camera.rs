//! RealSense D455 model and a column ray caster for the 2.5-D world.
//!
//! Every pixel column of a level pinhole camera looks along one vertical
//! plane, so one horizontal ray per column finds every prism that column can
//! see (sorted entry/exit distances); each row then resolves, from its
//! elevation, whether its ray first meets the floor, a prism's side or a
//! prism's top. The ray direction is scaled so its parameter *is* the optical
//! z (the depth a RealSense reports), so the result is exact, not sampled.

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::geometry::{Pose2, Shape, Span, Vec2};
use crate::world::{Entity, Semantic, World};

/// Camera settings. Defaults: 640×480 with the paper's Gazebo intrinsics
/// (fx = fy = 343.159, cx = 320.5, cy = 240.5), the camera body 0.30 m ahead of
/// base_link's origin and 0.60 m above it (the front of a Husky's top rail,
/// on a short mast), level and facing forward; depth valid 0.3–10 m with
/// noise σ = 0.002·z² m (≈ 0.8 % at 4 m; the D455 is specified ≤ 2 %).
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
}

pub const PAPER_WIDTH: u32 = 640;
pub const PAPER_HEIGHT: u32 = 480;
pub const PAPER_F: f64 = 343.159;
pub const PAPER_CX: f64 = 320.5;
pub const PAPER_CY: f64 = 240.5;

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
            depth_noise_k: 0.002,
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
        Ok(())
    }

    /// World pose of the camera body for a robot at `robot` (planar part) and its height.
    pub fn pose_in_world(&self, robot: &Pose2) -> (Pose2, f64) {
        let p = robot.compose(&Pose2::new(self.mount[0], self.mount[1], self.mount_yaw));
        (p, self.mount[2])
    }
}

/// One rendered frame: RGB8, depth (u16 mm, 0 invalid), instance ids (u16,
/// 0 = nothing) and the table of instances that appear in it.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
    pub depth_mm: Vec<u16>,
    pub labels: Vec<u16>,
    pub instances: Vec<Entity>,
}

impl Frame {
    pub fn pixel(&self, u: u32, v: u32) -> ([u8; 3], u16, u16) {
        let i = (v * self.width + u) as usize;
        ([self.rgb[3 * i], self.rgb[3 * i + 1], self.rgb[3 * i + 2]], self.depth_mm[i], self.labels[i])
    }
}

/// A prism as the renderer sees it this frame (pedestrians at their current place).
struct Prism<'a> {
    entity: u16,
    shape: &'a Shape,
    height: f64,
    color: [u8; 3],
}

#[derive(Clone, Copy)]
struct Hit {
    span: Span,
    height: f64,
    entity: u16,
    color: [u8; 3],
}

#[derive(Clone, Copy)]
struct FloorHit {
    t_in: f64,
    t_out: f64,
    entity: u16,
    color: [u8; 3],
}

const SKY: [u8; 3] = [205, 222, 240];
/// Horizontal direction of the key light (for side shading).
const LIGHT: Vec2 = Vec2 { x: 0.6, y: 0.8 };

/// Reusable buffers of the renderer (no allocation per frame once warm).
#[derive(Default)]
pub struct Renderer {
    hits: Vec<Hit>,
    floor: Vec<FloorHit>,
    spans: Vec<Span>,
    seen: Vec<bool>,
    ped_shapes: Vec<Shape>,
    row_slope: Vec<f64>,
}

impl Renderer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Renders the world at time `t` from a robot at `robot` (world frame)
    /// into `frame`, drawing depth noise from `rng`.
    pub fn render<R: Rng>(
        &mut self,
        world: &World,
        cam: &CameraConfig,
        robot: &Pose2,
        t: f64,
        rng: &mut R,
        frame: &mut Frame,
    ) {
        let (w, h) = (cam.width as usize, cam.height as usize);
        frame.width = cam.width;
        frame.height = cam.height;
        frame.rgb.resize(w * h * 3, 0);
        frame.depth_mm.resize(w * h, 0);
        frame.labels.resize(w * h, 0);
        self.seen.clear();
        self.seen.resize(world.entities.len() + 1, false);

        let (cam_pose, cz) = cam.pose_in_world(robot);
        let origin = Vec2::from(cam_pose.position());
        let forward = Vec2::new(1.0, 0.0).rotate(cam_pose.theta);
        let left = Vec2::new(0.0, 1.0).rotate(cam_pose.theta);

        self.ped_shapes.clear();
        self.ped_shapes.extend(world.pedestrians.iter().map(|p| p.shape_at(t)));
        let mut prisms: Vec<Prism> = Vec::with_capacity(world.solids.len() + world.pedestrians.len());
        prisms.extend(world.solids.iter().map(|s| Prism {
            entity: s.entity,
            shape: &s.shape,
            height: s.height,
            color: s.color,
        }));
        prisms.extend(world.pedestrians.iter().zip(&self.ped_shapes).map(|(p, s)| Prism {
            entity: p.entity,
            shape: s,
            height: p.height,
            color: p.color,
        }));

        // Elevation slope of each row: height gained per metre of optical z.
        self.row_slope.clear();
        self.row_slope.extend((0..h).map(|v| -((v as f64) - cam.cy) / cam.fy));

        let floor_entity = 1u16;
        let noise_on = cam.depth_noise_k > 0.0;
        for u in 0..w {
            // Ray with unit forward component: its parameter is optical z.
            let d = forward.add(left.scale(-((u as f64) - cam.cx) / cam.fx));
            self.hits.clear();
            for p in &prisms {
                self.spans.clear();
                p.shape.ray_spans(origin, d, &mut self.spans);
                for s in &self.spans {
                    if s.t_out > 0.0 {
                        let span = Span { t_in: s.t_in.max(0.0), ..*s };
                        self.hits.push(Hit { span, height: p.height, entity: p.entity, color: p.color });
                    }
                }
            }
            self.hits.sort_by(|a, b| a.span.t_in.total_cmp(&b.span.t_in));
            self.floor.clear();
            for m in &world.markings {
                for shape in &m.shapes {
                    self.spans.clear();
                    shape.ray_spans(origin, d, &mut self.spans);
                    for s in &self.spans {
                        if s.t_out > 0.0 {
                            self.floor.push(FloorHit {
                                t_in: s.t_in,
                                t_out: s.t_out,
                                entity: m.entity,
                                color: m.color,
                            });
                        }
                    }
                }
            }
            let dn = d.norm();
            for v in 0..h {
                let slope = self.row_slope[v];
                let t_floor = if slope < 0.0 { cz / -slope } else { f64::INFINITY };
                // (t, entity, colour, shade)
                let mut surf: Option<(f64, u16, [u8; 3], f64)> = None;
                for hit in &self.hits {
                    if hit.span.t_in >= t_floor {
                        break;
                    }
                    let z_in = cz + slope * hit.span.t_in;
                    if z_in >= 0.0 && z_in <= hit.height {
                        let n = hit.span.normal_in;
                        let lambert = (n.dot(LIGHT)).abs();
                        // Side faces: darker the more they face away from the key light and with distance.
                        let shade = 0.55 + 0.40 * lambert;
                        surf = Some((hit.span.t_in, hit.entity, hit.color, shade));
                        break;
                    }
                    if z_in > hit.height && slope < 0.0 {
                        let t_top = (hit.height - cz) / slope;
                        if t_top <= hit.span.t_out {
                            surf = Some((t_top.max(hit.span.t_in), hit.entity, hit.color, 1.0));
                            break;
                        }
                    }
                }
                let (t, entity, color, shade) = match surf {
                    Some(s) => s,
                    None if t_floor.is_finite() => {
                        let mut entity = floor_entity;
                        let mut color = world.floor_color;
                        let mut shade = 0.92;
                        for m in &self.floor {
                            if t_floor >= m.t_in && t_floor <= m.t_out {
                                entity = m.entity;
                                color = m.color;
                                shade = 0.95;
                            }
                        }
                        if entity == floor_entity {
                            // A faint 1 m checker gives the floor texture.
                            let p = origin.add(d.scale(t_floor));
                            if ((p.x.floor() + p.y.floor()) as i64).rem_euclid(2) == 0 {
                                shade = 0.86;
                            }
                        }
                        (t_floor, entity, color, shade)
                    }
                    None => (f64::INFINITY, 0, SKY, 1.0),
                };
                let i = v * w + u;
                // Distance fog, mild, so far surfaces look flatter.
                let fog = if t.is_finite() { (1.0 - 0.012 * (t * dn)).max(0.75) } else { 1.0 };
                let k = shade * fog;
                frame.rgb[3 * i] = (color[0] as f64 * k).round().min(255.0) as u8;
                frame.rgb[3 * i + 1] = (color[1] as f64 * k).round().min(255.0) as u8;
                frame.rgb[3 * i + 2] = (color[2] as f64 * k).round().min(255.0) as u8;
                frame.labels[i] = entity;
                self.seen[entity as usize] = true;
                frame.depth_mm[i] = if t.is_finite() {
                    let z = if noise_on {
                        let n: f64 = StandardNormal.sample(rng);
                        t + n * cam.depth_noise_k * t * t
                    } else {
                        t
                    };
                    if z >= cam.depth_min_m && z <= cam.depth_max_m { (z * 1000.0).round() as u16 } else { 0 }
                } else {
                    0
                };
            }
        }
        frame.instances.clear();
        frame.instances.extend(world.entities.iter().filter(|e| self.seen[e.instance_id as usize]).cloned());
    }
}

/// The semantic class of label `id` in `frame`, if any.
pub fn semantic_of(frame: &Frame, id: u16) -> Option<Semantic> {
    frame.instances.iter().find(|e| e.instance_id == id).map(|e| e.semantic)
}
