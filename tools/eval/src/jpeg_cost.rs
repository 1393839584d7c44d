//! `vlnav bench jpeg`: what JPEG colour (the edge agent's `--colour-codec
//! jpeg`) costs the perception, and what it saves on the uplink
//! (docs/architecture.md, "Frames").
//!
//! The same 640×480 images go to the stages twice: as rendered, and after a
//! round trip through the encoder the edge agent uses and the decoder every
//! stage uses (`vlnav_geometry::rgb`).
//! - **Detector**, NanoDet at the executor's threshold (0.4):
//!   - on the calibration's canvases (`calibrate.rs`: registry photos with
//!     objects pasted at known boxes, so real texture), scored as the
//!     calibration scores them: recall (IoU ≥ 0.5, right class) and the hits'
//!     IoU with the pasted boxes;
//!   - on rendered frames of the `demo` and `lab` scenarios along a drive,
//!     against the boxes of their label images;
//!   - on both, the JPEG image's detections against the raw image's: the
//!     share of raw detections found again (same class, IoU ≥ 0.5), their
//!     IoU, and detections only the JPEG image has.
//! - **Segmenter** (the colour backend, which runs on colour in every
//!   perception mode): on the rendered frames, its hazard mask on the JPEG
//!   frame against its mask on the raw frame (IoU), each against the label
//!   image's hazard pixels (recall).
//! - **Codec**: bytes, encode and decode time (median, wall clock of this
//!   process), PSNR.

use std::path::PathBuf;
use std::time::Instant;

use image::RgbImage;
use serde::Serialize;
use vlnav_detector::detection::{DetectFilter, Detection};
use vlnav_detector::nanodet::{NanoDet, NanoDetFiles};
use vlnav_geometry::camera::Camera;
use vlnav_geometry::rgb::{self, Encoding};
use vlnav_segmenter::colour::default_classes;
use vlnav_segmenter::segment::{ColourBackend, FrameView, PointSettings, segment};
use vlnav_sim::{Simulator, Twist, load_scenario};

use crate::calibrate::{self, Canvas};

/// The executor's detection threshold, as the calibration uses it.
const MIN_SCORE: f32 = 0.4;
const NMS_IOU: f32 = 0.45;
const IOU_MATCH: f32 = 0.5;
/// A raw detection this sure is no near miss of the threshold.
const CONFIDENT: f32 = 0.5;
/// A labelled object smaller than this (pixels high) is not counted: the
/// calibration's smallest height bin.
const MIN_LABEL_HEIGHT: f32 = 12.0;
/// Semantic classes of the label image the segmenter's colour classes stand for.
const HAZARDS: [&str; 3] = ["restricted_zone", "cable", "hazard"];

/// `vlnav bench jpeg` settings.
#[derive(clap::Args, Clone, Debug)]
pub struct JpegCostArgs {
    /// Where deploy/fetch-models.sh put the models (nanodet/, photos/).
    #[arg(long, env = "VLNAV_MODELS_DIR", default_value = "models")]
    pub models_dir: PathBuf,
    /// Calibration canvases (the detector runs on each once raw and once per quality).
    #[arg(long, default_value_t = 120)]
    pub canvases: u32,
    /// Rendered frames of each scenario (demo, lab), along a drive.
    #[arg(long, default_value_t = 40)]
    pub sim_frames: u32,
    /// JPEG qualities to measure (the edge agent's --jpeg-quality).
    #[arg(long, value_delimiter = ',', default_values_t = [95u8, 85, 75, 50],
          value_parser = clap::value_parser!(u8).range(1..=100))]
    pub quality: Vec<u8>,
    /// Seed of the canvases and of the simulators.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// One JSON object on stdout instead of the text report.
    #[arg(long)]
    pub json: bool,
}

impl Default for JpegCostArgs {
    fn default() -> Self {
        Self {
            models_dir: PathBuf::from("models"),
            canvases: 120,
            sim_frames: 40,
            quality: vec![95, 85, 75, 50],
            seed: 1,
            json: false,
        }
    }
}

/// The codec on one set of images at one quality.
#[derive(Clone, Debug, Default, Serialize)]
pub struct CodecFigures {
    pub images: usize,
    pub raw_bytes: usize,
    pub mean_bytes: f64,
    pub encode_ms_median: f64,
    pub decode_ms_median: f64,
    pub psnr_db_mean: f64,
}

/// Detections against reference boxes (ground truth).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Recall {
    pub objects: usize,
    pub hits: usize,
    pub recall: f64,
    /// Mean IoU of the hits with their reference boxes.
    pub mean_iou: f64,
}

/// The JPEG image's detections against the raw image's.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Agreement {
    pub raw_detections: usize,
    /// Share of the raw detections found again (same class, IoU ≥ 0.5).
    pub found_again: f64,
    /// The raw detections scored at least 0.5, and the share of them found again.
    pub confident_raw_detections: usize,
    pub confident_found_again: f64,
    /// Mean IoU of those pairs.
    pub mean_iou: f64,
    /// Detections of the JPEG image matching no raw detection.
    pub only_in_jpeg: usize,
}

/// The segmenter's hazard mask on the JPEG frames against the raw frames'.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MaskFigures {
    /// Pixels marked on the raw frames.
    pub raw_pixels: u64,
    /// IoU of the JPEG frames' mask with the raw frames' (all frames pooled).
    pub iou_with_raw: f64,
    /// Share of the label image's hazard pixels the mask marks.
    pub label_recall: f64,
    /// The same per semantic class of the label image (restricted_zone,
    /// cable, hazard); NaN where none was in view.
    pub label_recall_by_class: Vec<(String, f64)>,
}

/// One quality on one set of images.
#[derive(Clone, Debug, Default, Serialize)]
pub struct QualityReport {
    pub quality: u8,
    pub codec: CodecFigures,
    pub recall: Recall,
    pub agreement: Agreement,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mask: Option<MaskFigures>,
}

/// One set of images: the raw baseline and each quality.
#[derive(Clone, Debug, Default, Serialize)]
pub struct SetReport {
    pub name: String,
    pub images: usize,
    pub raw_recall: Recall,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub raw_mask: Option<MaskFigures>,
    pub qualities: Vec<QualityReport>,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct JpegCostReport {
    pub detector: String,
    pub sets: Vec<SetReport>,
}

/// An image with its reference boxes and, for a rendered frame, what the
/// segmenter needs (depth, camera, the label image's hazard pixels).
struct Sample {
    img: RgbImage,
    truth: Vec<Detection>,
    rendered: Option<Rendered>,
}

struct Rendered {
    camera: Camera,
    depth_mm: Vec<u16>,
    /// Per pixel: 1 + index into [`HAZARDS`] of its label, 0 for none.
    hazard: Vec<u8>,
}

/// Greedy one-to-one matching, best IoU first within a class: pairs
/// (index into `reference`, index into `found`, IoU).
fn matches(reference: &[Detection], found: &[Detection]) -> Vec<(usize, usize, f32)> {
    let mut pairs: Vec<(usize, usize, f32)> = Vec::new();
    for (i, r) in reference.iter().enumerate() {
        for (j, f) in found.iter().enumerate() {
            let iou = r.iou(f);
            if f.class_id == r.class_id && iou >= IOU_MATCH {
                pairs.push((i, j, iou));
            }
        }
    }
    pairs.sort_by(|a, b| b.2.total_cmp(&a.2));
    let (mut used_r, mut used_f) = (vec![false; reference.len()], vec![false; found.len()]);
    pairs.retain(|&(i, j, _)| {
        let fresh = !used_r[i] && !used_f[j];
        if fresh {
            (used_r[i], used_f[j]) = (true, true);
        }
        fresh
    });
    pairs
}

fn recall(truth: &[&[Detection]], found: &[Vec<Detection>]) -> Recall {
    let mut r = Recall::default();
    let mut iou = 0.0;
    for (t, f) in truth.iter().zip(found) {
        let m = matches(t, f);
        r.objects += t.len();
        r.hits += m.len();
        iou += m.iter().map(|p| f64::from(p.2)).sum::<f64>();
    }
    r.recall = if r.objects > 0 { r.hits as f64 / r.objects as f64 } else { f64::NAN };
    r.mean_iou = if r.hits > 0 { iou / r.hits as f64 } else { f64::NAN };
    r
}

fn agreement(raw: &[Vec<Detection>], jpeg: &[Vec<Detection>]) -> Agreement {
    let mut a = Agreement::default();
    let (mut found, mut iou, mut confident_found) = (0usize, 0.0, 0usize);
    for (r, j) in raw.iter().zip(jpeg) {
        let m = matches(r, j);
        a.raw_detections += r.len();
        a.confident_raw_detections += r.iter().filter(|d| d.score >= CONFIDENT).count();
        confident_found += m.iter().filter(|p| r[p.0].score >= CONFIDENT).count();
        found += m.len();
        iou += m.iter().map(|p| f64::from(p.2)).sum::<f64>();
        a.only_in_jpeg += j.len() - m.len();
    }
    a.found_again = if a.raw_detections > 0 { found as f64 / a.raw_detections as f64 } else { f64::NAN };
    a.confident_found_again = if a.confident_raw_detections > 0 {
        confident_found as f64 / a.confident_raw_detections as f64
    } else {
        f64::NAN
    };
    a.mean_iou = if found > 0 { iou / found as f64 } else { f64::NAN };
    a
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn psnr(a: &[u8], b: &[u8]) -> f64 {
    let mse = a.iter().zip(b).map(|(x, y)| (f64::from(*x) - f64::from(*y)).powi(2)).sum::<f64>() / a.len() as f64;
    if mse == 0.0 { 99.0 } else { 10.0 * (255.0f64 * 255.0 / mse).log10() }
}

/// JPEG round trip of every image at `quality`, with the codec's figures.
fn round_trip(samples: &[Sample], quality: u8) -> anyhow::Result<(Vec<RgbImage>, CodecFigures)> {
    let mut out = Vec::with_capacity(samples.len());
    let (mut encode, mut decode, mut bytes, mut db) = (Vec::new(), Vec::new(), 0usize, 0.0);
    for s in samples {
        let (w, h) = s.img.dimensions();
        let t = Instant::now();
        let jpeg = rgb::encode_jpeg(w, h, s.img.as_raw(), quality)?;
        encode.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        let back = rgb::decode(Encoding::Jpeg, w, h, &jpeg)?;
        decode.push(t.elapsed().as_secs_f64() * 1e3);
        bytes += jpeg.len();
        db += psnr(s.img.as_raw(), back.as_raw());
        out.push(back);
    }
    let n = samples.len().max(1) as f64;
    let figures = CodecFigures {
        images: samples.len(),
        raw_bytes: samples.first().map_or(0, |s| s.img.as_raw().len()),
        mean_bytes: bytes as f64 / n,
        encode_ms_median: median(encode),
        decode_ms_median: median(decode),
        psnr_db_mean: db / n,
    };
    Ok((out, figures))
}

fn detect_all(det: &NanoDet, images: &[&RgbImage]) -> anyhow::Result<Vec<Vec<Detection>>> {
    let filter = DetectFilter { class_ids: vec![], min_score: MIN_SCORE };
    let mut out = Vec::with_capacity(images.len());
    for batch in images.chunks(4) {
        out.extend(det.detect(batch, &vec![filter.clone(); batch.len()], NMS_IOU)?);
    }
    Ok(out)
}

/// The segmenter's mask (any hazard class) on each rendered frame.
fn hazard_masks(samples: &[Sample], images: &[&RgbImage]) -> anyhow::Result<Vec<Vec<bool>>> {
    let backend = ColourBackend::new(default_classes());
    let settings = PointSettings::default();
    samples
        .iter()
        .zip(images)
        .filter_map(|(s, img)| s.rendered.as_ref().map(|r| (r, img)))
        .map(|(r, img)| {
            let view = FrameView { camera: r.camera, rgb: img.as_raw(), depth_mm: &r.depth_mm, semantics: None };
            let seg = segment(&backend, &view, None, 8, &settings).map_err(|e| anyhow::anyhow!("segmenter: {e}"))?;
            Ok(seg.mask.iter().map(|k| *k != 0).collect())
        })
        .collect()
}

fn mask_figures(samples: &[Sample], raw: &[Vec<bool>], other: &[Vec<bool>]) -> MaskFigures {
    let (mut raw_px, mut inter, mut union) = (0u64, 0u64, 0u64);
    // Per class of HAZARDS: labelled pixels, and those the mask marks.
    let (mut labelled, mut found) = ([0u64; HAZARDS.len()], [0u64; HAZARDS.len()]);
    let truths = samples.iter().filter_map(|s| s.rendered.as_ref().map(|r| &r.hazard));
    for ((r, o), truth) in raw.iter().zip(other).zip(truths) {
        for ((a, b), t) in r.iter().zip(o).zip(truth) {
            raw_px += u64::from(*a);
            inter += u64::from(*a && *b);
            union += u64::from(*a || *b);
            if *t > 0 {
                labelled[*t as usize - 1] += 1;
                found[*t as usize - 1] += u64::from(*b);
            }
        }
    }
    let share = |k: u64, n: u64| if n > 0 { k as f64 / n as f64 } else { f64::NAN };
    MaskFigures {
        raw_pixels: raw_px,
        iou_with_raw: share(inter, union),
        label_recall: share(found.iter().sum(), labelled.iter().sum()),
        label_recall_by_class: HAZARDS
            .iter()
            .enumerate()
            .map(|(i, name)| (name.to_string(), share(found[i], labelled[i])))
            .collect(),
    }
}

/// Measures one set of images at every quality.
fn measure_set(det: &NanoDet, name: &str, samples: &[Sample], qualities: &[u8]) -> anyhow::Result<SetReport> {
    let truth: Vec<&[Detection]> = samples.iter().map(|s| s.truth.as_slice()).collect();
    let raw_images: Vec<&RgbImage> = samples.iter().map(|s| &s.img).collect();
    let raw = detect_all(det, &raw_images)?;
    let rendered = samples.iter().any(|s| s.rendered.is_some());
    let raw_masks = if rendered { hazard_masks(samples, &raw_images)? } else { Vec::new() };
    let mut report = SetReport {
        name: name.into(),
        images: samples.len(),
        raw_recall: recall(&truth, &raw),
        raw_mask: rendered.then(|| mask_figures(samples, &raw_masks, &raw_masks)),
        qualities: Vec::new(),
    };
    for &q in qualities {
        let (decoded, codec) = round_trip(samples, q)?;
        let images: Vec<&RgbImage> = decoded.iter().collect();
        let found = detect_all(det, &images)?;
        let mask = if rendered {
            let masks = hazard_masks(samples, &images)?;
            Some(mask_figures(samples, &raw_masks, &masks))
        } else {
            None
        };
        report.qualities.push(QualityReport {
            quality: q,
            codec,
            recall: recall(&truth, &found),
            agreement: agreement(&raw, &found),
            mask,
        });
    }
    Ok(report)
}

/// The calibration's canvases, with their pasted boxes as the truth.
fn canvases(det: &NanoDet, args: &JpegCostArgs) -> anyhow::Result<Vec<Sample>> {
    let photos = calibrate::load_photos(&args.models_dir.join("photos"))?;
    let refs = calibrate::references(det, &photos)?;
    let mut rng = calibrate::canvas_rng(args.seed);
    Ok((0..args.canvases)
        .map(|_| {
            let Canvas { img, pasted, .. } = calibrate::canvas(&photos, &refs, &mut rng);
            let truth = pasted.iter().map(|p| p.gt).collect();
            Sample { img, truth, rendered: None }
        })
        .collect())
}

/// Rendered 640×480 frames of `scenario` along a drive: arcs left and right
/// at walking pace, a frame every 0.4 s.
fn rendered(scenario: &str, frames: u32, seed: u64) -> anyhow::Result<Vec<Sample>> {
    let world = load_scenario(scenario).map_err(|e| anyhow::anyhow!("scenario {scenario}: {e}"))?;
    let mut sim = Simulator::new(world, seed);
    let info = vlnav_edge_agent::convert::sim_camera_info(sim.camera());
    let camera = vlnav_geometry::convert::camera_from_proto(
        Some(&info),
        "camera",
        vlnav_geometry::convert::DepthDefaults::UNSET,
    )?;
    let mut out = Vec::new();
    for k in 0..frames {
        let turn = if (k / 10) % 2 == 0 { 0.5 } else { -0.5 };
        sim.step(Twist::new(0.35, turn), 0.4);
        let f = sim.render();
        let img = RgbImage::from_raw(f.width, f.height, f.rgb.clone()).ok_or_else(|| {
            anyhow::anyhow!("the simulator rendered {} bytes for {}x{}", f.rgb.len(), f.width, f.height)
        })?;
        // Each labelled COCO object's box: the extent of its pixels.
        let mut truth = Vec::new();
        for e in f.instances.iter().filter(|e| e.class_id >= 0) {
            let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
            for (i, _) in f.labels.iter().enumerate().filter(|(_, id)| **id == e.instance_id) {
                let (x, y) = (i as u32 % f.width, i as u32 / f.width);
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
            }
            if x1 > x0 && (y1 - y0) as f32 >= MIN_LABEL_HEIGHT {
                truth.push(Detection {
                    x_min: x0 as f32,
                    y_min: y0 as f32,
                    x_max: x1 as f32,
                    y_max: y1 as f32,
                    class_id: e.class_id,
                    score: 1.0,
                });
            }
        }
        let hazard_of: Vec<(u16, u8)> = f
            .instances
            .iter()
            .filter_map(|e| {
                let k = HAZARDS.iter().position(|h| *h == e.semantic.as_str())?;
                Some((e.instance_id, k as u8 + 1))
            })
            .collect();
        let hazard = f.labels.iter().map(|id| hazard_of.iter().find(|(i, _)| i == id).map_or(0, |(_, k)| *k)).collect();
        out.push(Sample { img, truth, rendered: Some(Rendered { camera, depth_mm: f.depth_mm, hazard }) });
    }
    Ok(out)
}

/// Runs every measurement.
pub fn measure(args: &JpegCostArgs) -> anyhow::Result<JpegCostReport> {
    anyhow::ensure!(!args.quality.is_empty(), "--quality needs at least one value from 1 to 100");
    if let Some(q) = args.quality.iter().find(|q| !(1..=100).contains(*q)) {
        anyhow::bail!("--quality {q} is outside 1..=100");
    }
    let files = NanoDetFiles::in_dir(&args.models_dir.join("nanodet"));
    let det = NanoDet::load(&files, &candle_core::Device::Cpu)
        .map_err(|e| anyhow::anyhow!("{e}; run deploy/fetch-models.sh 30-nanodet 31-test-photos (or make models)"))?;
    let mut sets = Vec::new();
    if args.canvases > 0 {
        let samples = canvases(&det, args)?;
        sets.push(measure_set(&det, "calibration canvases (photos)", &samples, &args.quality)?);
    }
    if args.sim_frames > 0 {
        for scenario in ["demo", "lab"] {
            let samples = rendered(scenario, args.sim_frames, args.seed)?;
            sets.push(measure_set(&det, &format!("rendered frames, {scenario}"), &samples, &args.quality)?);
        }
    }
    Ok(JpegCostReport { detector: vlnav_detector::nanodet::MODEL_NAME.into(), sets })
}

fn pct(v: f64) -> String {
    if v.is_nan() { "–".into() } else { format!("{:.1} %", 100.0 * v) }
}

fn by_class(m: &MaskFigures) -> String {
    let known: Vec<String> =
        m.label_recall_by_class.iter().filter(|(_, r)| !r.is_nan()).map(|(c, r)| format!("{c} {}", pct(*r))).collect();
    known.join(", ")
}

fn num(v: f64) -> String {
    if v.is_nan() { "–".into() } else { format!("{v:.3}") }
}

impl std::fmt::Display for JpegCostReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "detector {}, threshold {MIN_SCORE}, matched at IoU >= {IOU_MATCH}", self.detector)?;
        for s in &self.sets {
            writeln!(f, "\n{} ({} images)", s.name, s.images)?;
            let r = &s.raw_recall;
            writeln!(
                f,
                "  raw:      recall {} ({}/{}), IoU {}{}",
                pct(r.recall),
                r.hits,
                r.objects,
                num(r.mean_iou),
                s.raw_mask.as_ref().map_or(String::new(), |m| format!(
                    "; segmenter {} px, {} of the labelled hazard pixels ({})",
                    m.raw_pixels,
                    pct(m.label_recall),
                    by_class(m)
                ))
            )?;
            for q in &s.qualities {
                let (c, r, a) = (&q.codec, &q.recall, &q.agreement);
                writeln!(
                    f,
                    "  jpeg q{:<3} {:>7.0} bytes ({} of raw), encode {:.1} ms, decode {:.1} ms, PSNR {:.1} dB",
                    q.quality,
                    c.mean_bytes,
                    pct(c.mean_bytes / c.raw_bytes.max(1) as f64),
                    c.encode_ms_median,
                    c.decode_ms_median,
                    c.psnr_db_mean
                )?;
                writeln!(
                    f,
                    "            recall {} ({}/{}), IoU {}; raw detections found again {} of {} (IoU {}; \
                     scored >= {CONFIDENT}: {} of {}), {} only in JPEG",
                    pct(r.recall),
                    r.hits,
                    r.objects,
                    num(r.mean_iou),
                    pct(a.found_again),
                    a.raw_detections,
                    num(a.mean_iou),
                    pct(a.confident_found_again),
                    a.confident_raw_detections,
                    a.only_in_jpeg
                )?;
                if let Some(m) = &q.mask {
                    writeln!(
                        f,
                        "            segmenter mask IoU with raw {}, {} of the labelled hazard pixels ({})",
                        num(m.iou_with_raw),
                        pct(m.label_recall),
                        by_class(m)
                    )?;
                }
            }
        }
        Ok(())
    }
}

/// `vlnav bench jpeg`: measures and prints the report.
pub fn run(args: &JpegCostArgs, out: &mut impl std::io::Write) -> anyhow::Result<JpegCostReport> {
    let report = measure(args)?;
    if args.json {
        writeln!(out, "{}", serde_json::to_string(&report)?)?;
    } else {
        write!(out, "{report}")?;
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn b(x: f32, y: f32, w: f32, h: f32, class_id: i32) -> Detection {
        Detection { x_min: x, y_min: y, x_max: x + w, y_max: y + h, class_id, score: 0.9 }
    }

    #[test]
    fn matching_is_one_to_one_within_a_class_at_iou_half() {
        let truth = [b(0.0, 0.0, 10.0, 10.0, 0), b(50.0, 50.0, 10.0, 10.0, 1)];
        // A good box, a duplicate of it, the second object as another class.
        let found = [b(1.0, 0.0, 10.0, 10.0, 0), b(0.0, 1.0, 10.0, 10.0, 0), b(50.0, 50.0, 10.0, 10.0, 2)];
        let m = matches(&truth, &found);
        assert_eq!(m.len(), 1);
        assert_eq!((m[0].0, m[0].1), (0, 0));
        let r = recall(&[&truth], &[found.to_vec()]);
        assert_eq!((r.objects, r.hits), (2, 1));
        assert!((r.recall - 0.5).abs() < 1e-9 && r.mean_iou > 0.8);
        let a = agreement(&[truth.to_vec()], &[found.to_vec()]);
        assert_eq!((a.raw_detections, a.only_in_jpeg, a.confident_raw_detections), (2, 2, 2));
        assert!((a.found_again - 0.5).abs() < 1e-9 && (a.confident_found_again - 0.5).abs() < 1e-9);
        // Nothing to find is not a recall of zero.
        assert!(recall(&[&[]], &[vec![]]).recall.is_nan());
    }

    #[test]
    fn psnr_and_medians() {
        assert_eq!(psnr(&[1, 2, 3], &[1, 2, 3]), 99.0);
        // An error of 1 on every sample: 10·log10(255²) ≈ 48.13 dB.
        assert!((psnr(&[10; 30], &[11; 30]) - 48.13).abs() < 0.01);
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert!(median(vec![]).is_nan());
    }

    #[test]
    fn rendered_frames_carry_their_hazards_and_objects_and_a_jpeg_mask_stays_close() {
        let samples = rendered("lab", 3, 1).unwrap();
        assert_eq!(samples.len(), 3);
        let s = &samples[0];
        assert_eq!(s.img.dimensions(), (640, 480));
        let hazard_px: usize =
            samples.iter().map(|s| s.rendered.as_ref().unwrap().hazard.iter().filter(|h| **h > 0).count()).sum();
        assert!(hazard_px > 0, "the lab's red zone and cables are in view");
        let raw: Vec<&RgbImage> = samples.iter().map(|s| &s.img).collect();
        let raw_masks = hazard_masks(&samples, &raw).unwrap();
        let (decoded, codec) = round_trip(&samples, 85).unwrap();
        assert!(codec.mean_bytes < codec.raw_bytes as f64 / 10.0 && codec.psnr_db_mean > 30.0, "{codec:?}");
        let jpeg: Vec<&RgbImage> = decoded.iter().collect();
        let m = mask_figures(&samples, &raw_masks, &hazard_masks(&samples, &jpeg).unwrap());
        assert!(m.raw_pixels > 0 && m.iou_with_raw > 0.8, "{m:?}");
        assert_eq!(m.label_recall_by_class.len(), HAZARDS.len());
    }
}
