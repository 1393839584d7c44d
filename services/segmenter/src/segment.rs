//! The segmentation pipeline: a backend labels pixels with semantic classes;
//! depth then keeps floor-only classes to pixels whose 3-D point lies on the
//! floor plane, and the kept pixels become virtual obstacle points in
//! base_link, stacked from the floor up (by default at 0, 0.25 and 0.5 m) so
//! the local planner treats the zone as a wall it cannot cross.

use std::collections::HashMap;

use vlnav_geometry::camera::{Camera, Projector};

use crate::colour::{ColourClass, Labeller, rgb_to_hsv};

/// One RGB-D frame in domain terms (sizes already checked against `camera`).
pub struct FrameView<'a> {
    pub camera: Camera,
    /// RGB8, row-major, width·height·3.
    pub rgb: &'a [u8],
    /// Millimetres, row-major, width·height; 0 = no return.
    pub depth_mm: &'a [u16],
    /// Per-pixel semantic class name from a simulator label image, if any.
    pub semantics: Option<&'a SemanticLabels>,
}

/// A simulator label image reduced to semantics: instance id per pixel and
/// each instance's semantic class.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SemanticLabels {
    pub ids: Vec<u16>,
    pub semantic: HashMap<u32, String>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SegmentError {
    #[error("{0}")]
    InvalidInput(String),
}

/// Labels pixels with the backend's classes. A later RGB-D network
/// (ESANet-style) is one more implementation of this trait.
pub trait SegmentBackend: Send {
    fn name(&self) -> &'static str;
    /// The semantic classes it can report, in a fixed order.
    fn classes(&self) -> Vec<String>;
    /// Whether class `i` (index into `classes()`) marks something on the floor.
    fn floor_only(&self, i: usize) -> bool;
    /// Per pixel: 1 + index into `classes()` of the first wanted class that
    /// matches, 0 for none. `wanted[i]` says whether class `i` was asked for.
    fn label(&self, frame: &FrameView, wanted: &[bool]) -> Result<Vec<u8>, SegmentError>;
    /// What the backend reads from a frame besides depth, which every
    /// backend reads (the floor check and the points).
    fn reads(&self) -> Reads;
}

/// The parts of a frame a backend reads besides depth.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reads {
    pub rgb: bool,
    /// The simulator's label image.
    pub labels: bool,
}

/// Thresholds colour in HSV.
pub struct ColourBackend {
    classes: Vec<ColourClass>,
}

impl ColourBackend {
    pub fn new(classes: Vec<ColourClass>) -> Self {
        Self { classes }
    }
}

impl SegmentBackend for ColourBackend {
    fn name(&self) -> &'static str {
        "colour"
    }

    fn classes(&self) -> Vec<String> {
        self.classes.iter().map(|c| c.name.clone()).collect()
    }

    fn floor_only(&self, i: usize) -> bool {
        self.classes[i].floor_only
    }

    fn reads(&self) -> Reads {
        Reads { rgb: true, labels: false }
    }

    fn label(&self, frame: &FrameView, wanted: &[bool]) -> Result<Vec<u8>, SegmentError> {
        let active: Vec<(u8, &ColourClass)> =
            self.classes.iter().enumerate().filter(|(i, _)| wanted[*i]).map(|(i, c)| (i as u8 + 1, c)).collect();
        let pixels = frame.rgb.chunks_exact(3);
        Ok(match Labeller::new(&active) {
            Some(labeller) => pixels.map(|p| labeller.label([p[0], p[1], p[2]])).collect(),
            None => pixels
                .map(|p| {
                    let hsv = rgb_to_hsv([p[0], p[1], p[2]]);
                    active.iter().find(|(_, c)| c.ranges.iter().any(|r| r.contains(hsv))).map_or(0, |(k, _)| *k)
                })
                .collect(),
        })
    }
}

/// Reads semantics from the simulator's label image (`LabelInstance.semantic`).
pub struct SimBackend;

/// Semantic classes of the simulator that are hazards (floor markings and cables).
pub const SIM_CLASSES: [&str; 3] = ["restricted_zone", "cable", "hazard"];

impl SegmentBackend for SimBackend {
    fn name(&self) -> &'static str {
        "sim"
    }

    fn classes(&self) -> Vec<String> {
        SIM_CLASSES.iter().map(|s| s.to_string()).collect()
    }

    fn floor_only(&self, _i: usize) -> bool {
        true
    }

    fn reads(&self) -> Reads {
        Reads { rgb: false, labels: true }
    }

    fn label(&self, frame: &FrameView, wanted: &[bool]) -> Result<Vec<u8>, SegmentError> {
        let labels = frame.semantics.ok_or_else(|| {
            SegmentError::InvalidInput(
                "frame.labels: the simulation backend reads semantics from the label image, and this frame has none"
                    .into(),
            )
        })?;
        let class_of: HashMap<u32, u8> = labels
            .semantic
            .iter()
            .filter_map(|(id, s)| {
                let k = SIM_CLASSES.iter().position(|c| c == s)?;
                wanted[k].then_some((*id, k as u8 + 1))
            })
            .collect();
        Ok(labels.ids.iter().map(|id| class_of.get(&(*id as u32)).copied().unwrap_or(0)).collect())
    }
}

/// Post-processing settings.
#[derive(Clone, Debug, PartialEq)]
pub struct PointSettings {
    /// Height of the floor plane in base_link, metres.
    pub floor_z_m: f64,
    /// A floor-only pixel is kept when its point is within this of the floor, metres.
    pub floor_tolerance_m: f64,
    /// Heights above the floor at which each kept pixel becomes a point, metres.
    pub layers_m: Vec<f64>,
}

impl Default for PointSettings {
    fn default() -> Self {
        Self { floor_z_m: 0.0, floor_tolerance_m: 0.10, layers_m: vec![0.0, 0.25, 0.5] }
    }
}

/// The result in domain terms.
#[derive(Clone, Debug, PartialEq)]
pub struct Segmentation {
    /// The reported classes, in order.
    pub classes: Vec<String>,
    /// Per pixel: 1 + index into `classes`, 0 = none.
    pub mask: Vec<u8>,
    pub class_pixels: Vec<u32>,
    /// base_link points, metres.
    pub points: Vec<[f64; 3]>,
}

/// Runs `backend` for the requested classes (`None`: all) and turns the
/// result into a mask and virtual points, sampling every `stride`-th pixel
/// in each direction for points.
pub fn segment(
    backend: &dyn SegmentBackend,
    frame: &FrameView,
    requested: Option<&[String]>,
    stride: usize,
    settings: &PointSettings,
) -> Result<Segmentation, SegmentError> {
    let known = backend.classes();
    let classes: Vec<String> = match requested {
        None => known.clone(),
        Some(r) => r.to_vec(),
    };
    // Backend index → response index.
    let mut to_response = vec![0u8; known.len()];
    for (j, c) in classes.iter().enumerate() {
        let i = known.iter().position(|k| k == c).ok_or_else(|| {
            SegmentError::InvalidInput(format!(
                "classes[{j}]: {c:?} is not known to the {} backend (known: {})",
                backend.name(),
                known.join(", ")
            ))
        })?;
        if to_response[i] != 0 {
            return Err(SegmentError::InvalidInput(format!("classes[{j}]: {c:?} is listed twice")));
        }
        to_response[i] = j as u8 + 1;
    }
    let wanted: Vec<bool> = to_response.iter().map(|&r| r != 0).collect();
    let raw = backend.label(frame, &wanted)?;

    let (w, h) = (frame.camera.width as usize, frame.camera.height as usize);
    let projector = Projector::new(&frame.camera);
    let rays = FloorRays::new(&projector);
    let stride = stride.max(1);
    let mut mask = vec![0u8; w * h];
    let mut class_pixels = vec![0u32; classes.len()];
    let mut points = Vec::new();
    for v in 0..h {
        for u in 0..w {
            let idx = v * w + u;
            let k = raw[idx];
            if k == 0 {
                continue;
            }
            let class = k as usize - 1;
            let depth = projector.valid_depth(frame.depth_mm[idx]);
            let point = depth.map(|d| projector.project(u as f64, v as f64, d));
            if backend.floor_only(class) {
                // Unverifiable (no depth) or off the floor (a poster on a wall): not a floor zone.
                match point {
                    Some(p) if (p.z - settings.floor_z_m).abs() <= settings.floor_tolerance_m => {}
                    _ => continue,
                }
                // The foot of something standing (a red hydrant's base, a
                // walker's red shoes): within the tolerance of the floor,
                // but the surface rises there.
                if rises_above(frame, &projector, &rays, (u, v), depth.unwrap_or(0.0), settings.floor_z_m) {
                    continue;
                }
            }
            let r = to_response[class];
            mask[idx] = r;
            class_pixels[r as usize - 1] += 1;
            if let Some(p) = point
                && u % stride == 0
                && v % stride == 0
            {
                let (at, base) = if backend.floor_only(class) {
                    // On the floor the pixel's ray places it better than its
                    // depth: the D455's error grows with the square of range
                    // (σ = 0.005·z², 0.18 m at 6 m along the ray;
                    // docs/perception.md, "Depth"), where the ray meets a
                    // flat floor as exactly as the camera is calibrated.
                    let on_floor = rays.depth(u as f64, v as f64, settings.floor_z_m);
                    let at = if on_floor.is_finite() { projector.project(u as f64, v as f64, on_floor) } else { p };
                    (at, settings.floor_z_m)
                } else {
                    (p, p.z)
                };
                points.extend(settings.layers_m.iter().map(|dz| [at.x, at.y, base + dz]));
            }
        }
    }
    Ok(Segmentation { classes, mask, class_pixels, points })
}

/// A floor marking lies flat; the foot of an object rises. The test looks
/// up the image from the pixel to the first row where a flat floor would
/// be at least `FLAT_SEPARATION_M` and four of the D455's σ farther along
/// the ray than the pixel (σ = 0.005·z², docs/perception.md, "Depth"), so
/// that the depth measured there tells the floor from an upright face.
const FLAT_SEPARATION_M: f64 = 0.15;
const D455_NOISE_K: f64 = 0.005;
/// Rows searched upward for that row (0.15 m up a face 1 m away is 58 rows
/// of a 640 × 480 image); none found (the top of the image): no test.
const FLAT_SEARCH_ROWS: usize = 64;

/// Where pixels' rays meet the floor: a ray's height per metre of optical
/// depth is affine in the pixel (`Projector::project` is, at a fixed
/// depth), so the floor's optical depth at any pixel is two multiplies
/// away.
struct FloorRays {
    origin_z: f64,
    z0: f64,
    zu: f64,
    zv: f64,
}

impl FloorRays {
    fn new(projector: &Projector) -> Self {
        let origin = projector.project(0.0, 0.0, 0.0);
        let r00 = projector.project(0.0, 0.0, 1.0) - origin;
        let zu = projector.project(1.0, 0.0, 1.0).z - origin.z - r00.z;
        let zv = projector.project(0.0, 1.0, 1.0).z - origin.z - r00.z;
        Self { origin_z: origin.z, z0: r00.z, zu, zv }
    }

    /// Optical depth at which pixel `(u, v)`'s ray meets the floor at
    /// height `floor_z`; infinite at or above the horizon.
    fn depth(&self, u: f64, v: f64, floor_z: f64) -> f64 {
        let dz = self.z0 + self.zu * u + self.zv * v;
        if dz < -1e-9 { (floor_z - self.origin_z) / dz } else { f64::INFINITY }
    }
}

/// Whether the surface at pixel `(u, v)`, seen at optical depth `depth`
/// (m), rises like the side of an object rather than lying flat like the
/// floor at height `floor_z`: at the first row above it where a flat floor
/// would lie far enough beyond it, the measured depth is nearer the
/// pixel's own (an upright face) than the floor's. A hole there looks on
/// up; none found: flat.
fn rises_above(
    frame: &FrameView,
    projector: &Projector,
    rays: &FloorRays,
    (u, v): (usize, usize),
    depth: f64,
    floor_z: f64,
) -> bool {
    let w = frame.camera.width as usize;
    let separation = FLAT_SEPARATION_M.max(4.0 * D455_NOISE_K * depth * depth);
    for k in 1..=FLAT_SEARCH_ROWS.min(v) {
        let row = v - k;
        let floor_depth = rays.depth(u as f64, row as f64, floor_z);
        if floor_depth - depth < separation {
            continue;
        }
        let Some(measured) = projector.valid_depth(frame.depth_mm[row * w + u]) else { continue };
        return (measured - depth).abs() < (floor_depth - measured).abs();
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::colour::default_classes;
    use nalgebra::Vector3;
    use vlnav_geometry::camera::{Intrinsics, Mount};

    /// A camera 1 m above the floor looking straight down (pitch +90°): every
    /// pixel sees the floor at 1 m, image up (−v) is base_link +x.
    fn downward(w: u32, h: u32) -> Camera {
        Camera {
            width: w,
            height: h,
            intrinsics: Intrinsics { fx: 2.0, fy: 2.0, cx: (w as f64 - 1.0) / 2.0, cy: (h as f64 - 1.0) / 2.0 },
            mount: Mount {
                translation: Vector3::new(0.0, 0.0, 1.0),
                roll: 0.0,
                pitch: std::f64::consts::FRAC_PI_2,
                yaw: 0.0,
            },
            depth_min_m: 0.0,
            depth_max_m: 0.0,
        }
    }

    #[test]
    fn floor_pixels_become_stacked_points_and_unverifiable_ones_are_dropped() {
        let cam = downward(3, 3);
        let red = [220u8, 20, 20];
        let grey = [128u8, 128, 128];
        // Red everywhere but the centre; the top-left reading is missing and
        // the top-right one is a box top 0.6 m above the floor.
        let rgb: Vec<u8> = (0..9).flat_map(|i| if i == 4 { grey } else { red }).collect();
        let mut depth = vec![1000u16; 9];
        depth[0] = 0;
        depth[2] = 400;
        let frame = FrameView { camera: cam, rgb: &rgb, depth_mm: &depth, semantics: None };
        let backend = ColourBackend::new(default_classes());
        let seg = segment(&backend, &frame, None, 1, &PointSettings::default()).unwrap();
        assert_eq!(seg.mask, vec![0, 1, 0, 1, 0, 1, 1, 1, 1]);
        assert_eq!(seg.class_pixels, vec![6, 0, 0]);
        assert_eq!(seg.points.len(), 6 * 3);
        // Pixel (1, 0) — top middle — lies 0.5 m ahead (fx = 2, 1 px at 1 m).
        let ahead: Vec<_> = seg.points.iter().filter(|p| p[0] > 0.4).collect();
        assert_eq!(ahead.len(), 3);
        for (p, z) in ahead.iter().zip([0.0, 0.25, 0.5]) {
            assert!((p[0] - 0.5).abs() < 1e-9 && p[1].abs() < 1e-9 && (p[2] - z).abs() < 1e-12, "{p:?}");
        }
        // A stride of 2 keeps pixels (0,0), (2,0), (0,2), (2,2): only the bottom two qualify.
        let sparse = segment(&backend, &frame, None, 2, &PointSettings::default()).unwrap();
        assert_eq!(sparse.points.len(), 2 * 3);
        assert_eq!(sparse.mask, seg.mask, "the stride thins points, not the mask");
    }

    #[test]
    fn requested_classes_are_checked_and_reordered() {
        let cam = downward(1, 1);
        let frame = FrameView { camera: cam, rgb: &[240, 210, 20], depth_mm: &[1000], semantics: None };
        let backend = ColourBackend::new(default_classes());
        let wanted = ["cable".to_string(), "hazard".to_string()];
        let seg = segment(&backend, &frame, Some(&wanted), 1, &PointSettings::default()).unwrap();
        assert_eq!(
            (seg.classes.as_slice(), seg.mask.as_slice(), seg.class_pixels.as_slice()),
            (&wanted[..], &[2u8][..], &[0, 1][..])
        );
        let twice = ["hazard".to_string(), "hazard".to_string()];
        assert!(segment(&backend, &frame, Some(&twice), 1, &PointSettings::default()).is_err());
        let unknown = ["lava".to_string()];
        let err = segment(&backend, &frame, Some(&unknown), 1, &PointSettings::default()).unwrap_err();
        assert!(err.to_string().contains("lava"), "{err}");
    }
}
