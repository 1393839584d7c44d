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

pub use crate::camera_config::{CameraConfig, D455_NOISE_K, PAPER_CX, PAPER_CY, PAPER_F, PAPER_HEIGHT, PAPER_WIDTH};
use crate::geometry::{Pose2, Shape, Span, Vec2};
use crate::world::{Entity, Semantic, World};

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
    /// Per entry of `instances`: the share of its unoccluded, untruncated
    /// projection that is in view (1 for floor markings and structure
    /// seen whole, ≤ 1 for anything hidden behind something or cut by the
    /// image border).
    pub visible_fraction: Vec<f32>,
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
    /// Noise-free optical z per pixel (for the stereo holes), metres.
    zbuf: Vec<f32>,
    /// Per entity: pixels in view, pixels of its unoccluded projection in
    /// the image's columns, last column counted.
    vis_px: Vec<f64>,
    full_px: Vec<f64>,
    full_col: Vec<u32>,
}

impl Renderer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Renders the world from a robot at `robot` (world frame), the world's
    /// pedestrians standing at `people` (in the world's order), into
    /// `frame`, drawing depth noise from `rng`.
    pub fn render<R: Rng>(
        &mut self,
        world: &World,
        cam: &CameraConfig,
        robot: &Pose2,
        people: &[Vec2],
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
        let n_ent = world.entities.len() + 1;
        self.vis_px.clear();
        self.vis_px.resize(n_ent, 0.0);
        self.full_px.clear();
        self.full_px.resize(n_ent, 0.0);
        self.full_col.clear();
        self.full_col.resize(n_ent, u32::MAX);
        self.zbuf.clear();
        self.zbuf.resize(w * h, f32::INFINITY);

        let (cam_pose, cz) = cam.pose_in_world(robot);
        let origin = Vec2::from(cam_pose.position());
        let forward = Vec2::new(1.0, 0.0).rotate(cam_pose.theta);
        let left = Vec2::new(0.0, 1.0).rotate(cam_pose.theta);

        self.ped_shapes.clear();
        self.ped_shapes
            .extend(world.pedestrians.iter().zip(people).map(|(p, c)| Shape::Circle { centre: *c, radius: p.radius }));
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
            let d = forward + left.scale(-((u as f64) - cam.cx) / cam.fx);
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
            // Rows each prism would cover in this column were nothing in
            // front of it (its near face, and its top when below the camera).
            for hit in &self.hits {
                let e = hit.entity as usize;
                if self.full_col[e] == u as u32 {
                    continue;
                }
                self.full_col[e] = u as u32;
                let t_near = hit.span.t_in.max(0.05);
                let t_far = if hit.height < cz { hit.span.t_out.max(t_near) } else { t_near };
                let v_top = cam.cy - cam.fy * (hit.height - cz) / t_far;
                let v_bottom = cam.cy + cam.fy * cz / t_near;
                self.full_px[e] += (v_bottom - v_top).max(0.0);
            }
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
                            let p = origin + d.scale(t_floor);
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
                self.vis_px[entity as usize] += 1.0;
                self.zbuf[i] = t as f32;
                frame.depth_mm[i] = if t.is_finite() {
                    let z = if noise_on {
                        let n: f64 = StandardNormal.sample(rng);
                        t + n * cam.depth_noise_k * t * t
                    } else {
                        t
                    };
                    // Beyond the reliable range a growing share of pixels has no match.
                    let lost = if t > cam.depth_reliable_max_m {
                        let p = 0.5 * (t - cam.depth_reliable_max_m)
                            / (cam.depth_max_m - cam.depth_reliable_max_m).max(1e-6);
                        rng.random::<f64>() < p
                    } else {
                        false
                    };
                    if !lost && z >= cam.depth_min_m && z <= cam.depth_max_m { (z * 1000.0).round() as u16 } else { 0 }
                } else {
                    0
                };
            }
        }
        if cam.stereo_baseline_m > 0.0 {
            stereo_holes(&self.zbuf, w, h, cam.fx * cam.stereo_baseline_m, &mut frame.depth_mm);
        }
        frame.instances.clear();
        frame.visible_fraction.clear();
        for e in world.entities.iter().filter(|e| self.seen[e.instance_id as usize]) {
            let id = e.instance_id as usize;
            let shape = prisms.iter().find(|p| p.entity == e.instance_id).map(|p| p.shape);
            let occlusion = if self.full_px[id] > 0.0 { (self.vis_px[id] / self.full_px[id]).min(1.0) } else { 1.0 };
            let truncation = shape.map(|s| in_view_share(s, origin, forward, left, cam)).unwrap_or(1.0);
            frame.instances.push(e.clone());
            frame.visible_fraction.push((occlusion * truncation) as f32);
        }
    }
}

/// Invalidates the occlusion band of a stereo camera whose reference imager
/// is the left one: left of every place where a row steps to a nearer
/// surface, background pixels the right imager cannot see have no match.
/// The band is `fb · (1/z_near − 1/z_far)` pixels wide (`fb` = focal length
/// in pixels × baseline in metres).
fn stereo_holes(z: &[f32], w: usize, h: usize, fb: f64, depth_mm: &mut [u16]) {
    for v in 0..h {
        let row = &z[v * w..(v + 1) * w];
        for u in 1..w {
            let (far, near) = (row[u - 1], row[u]);
            // A step to a nearer surface (far is infinite where nothing was hit).
            let step = near.is_finite() && near > 0.0 && far > near * 1.1 + 0.05;
            if !step {
                continue;
            }
            let inv_far = if far.is_finite() { 1.0 / f64::from(far) } else { 0.0 };
            let band = (fb * (1.0 / f64::from(near) - inv_far)).round() as usize;
            for k in u.saturating_sub(band)..u {
                depth_mm[v * w + k] = 0;
            }
        }
    }
}

/// The share of a shape's horizontal extent that falls inside the image
/// (1 when whole; the rest is cut off by the image border or behind the camera).
fn in_view_share(shape: &Shape, origin: Vec2, forward: Vec2, left: Vec2, cam: &CameraConfig) -> f64 {
    let (lo, hi) = shape.bounds();
    let mut u_min = f64::INFINITY;
    let mut u_max = f64::NEG_INFINITY;
    for p in [Vec2::new(lo.x, lo.y), Vec2::new(hi.x, lo.y), Vec2::new(hi.x, hi.y), Vec2::new(lo.x, hi.y)] {
        let r = p - origin;
        let (x, y) = (r.dot(forward), r.dot(left));
        if x < 0.05 {
            // Part of it is beside or behind the camera: that side runs off the image.
            if y > 0.0 {
                u_min = f64::NEG_INFINITY;
            } else {
                u_max = f64::INFINITY;
            }
            continue;
        }
        let u = cam.cx - cam.fx * y / x;
        u_min = u_min.min(u);
        u_max = u_max.max(u);
    }
    if u_max.partial_cmp(&u_min) != Some(std::cmp::Ordering::Greater) {
        return 1.0;
    }
    if u_min.is_infinite() || u_max.is_infinite() {
        // Unbounded: the in-view part is small against what lies beyond.
        let inside = (u_max.min(cam.width as f64) - u_min.max(0.0)).max(0.0);
        return (inside / (inside + cam.width as f64)).clamp(0.0, 1.0);
    }
    let inside = (u_max.min(cam.width as f64) - u_min.max(0.0)).max(0.0);
    (inside / (u_max - u_min)).clamp(0.0, 1.0)
}

/// The semantic class of label `id` in `frame`, if any.
pub fn semantic_of(frame: &Frame, id: u16) -> Option<Semantic> {
    frame.instances.iter().find(|e| e.instance_id == id).map(|e| e.semantic)
}
