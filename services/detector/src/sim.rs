//! The simulation backend: detections read from the simulator's label image
//! (per-pixel instance ids) instead of a network.
//!
//! Two behaviours:
//! - **oracle** (no error model): an instance is detected when its class is
//!   a COCO class, enough of it is visible (occlusion is already in the label
//!   image: hidden pixels belong to the occluder) and it is within range by
//!   its median depth; optional flat misses and box jitter;
//! - **realistic** (an [`error_model::DetectorModel`], measured on the real
//!   detector): each instance is found with the recall its apparent height
//!   and visible fraction earn, may be reported as a confusable class, its
//!   box jitters, its confidence is drawn from the measured distribution,
//!   and false positives appear at the measured rate.
//!
//! Every random choice is a deterministic function of (seed, robot, frame
//! seq, instance id), so simulated runs reproduce exactly.

use std::collections::HashMap;
use std::sync::Arc;

use crate::detection::{DetectFilter, Detection};
use crate::error_model::{DetectorModel, Draws, REFERENCE_HEIGHT_PX, from_deciles};

/// One entry of the label image's instance table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instance {
    pub instance_id: u32,
    /// COCO-80 class id, or −1 for structure and floor.
    pub class_id: i32,
    /// Share of the instance's unoccluded, untruncated projection in view (0–1).
    pub visible_fraction: f32,
}

/// A label image with its aligned depth.
#[derive(Clone, Debug, PartialEq)]
pub struct LabeledFrame {
    /// Hash of the robot id ([`crate::error_model::hash_str`]): robots draw independent errors.
    pub robot: u64,
    pub seq: u64,
    pub width: u32,
    pub height: u32,
    /// Instance id per pixel, row-major (0 = nothing).
    pub instance_ids: Vec<u16>,
    pub instances: Vec<Instance>,
    /// Depth per pixel in millimetres (0 = no return), same size; empty when the frame has none.
    pub depth_mm: Vec<u16>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LabelError {
    #[error("frame.labels is empty; the simulation backend needs the simulator's label image")]
    Missing,
    #[error("frame.labels.{field} has {got} bytes, expected {expected} ({width}×{height}×2, little-endian u16)")]
    Length { field: &'static str, got: usize, expected: usize, width: u32, height: u32 },
    #[error("frame.depth is {dw}×{dh} but frame.labels is {width}×{height}; they must be aligned")]
    DepthSize { dw: u32, dh: u32, width: u32, height: u32 },
}

/// Little-endian u16 pixels, checked against the size.
pub fn parse_u16_image(field: &'static str, width: u32, height: u32, bytes: &[u8]) -> Result<Vec<u16>, LabelError> {
    // A declared size near u32::MAX a side overflows; it matches no buffer.
    let expected = (width as usize).checked_mul(height as usize).and_then(|p| p.checked_mul(2)).unwrap_or(usize::MAX);
    if bytes.len() != expected {
        return Err(LabelError::Length { field, got: bytes.len(), expected, width, height });
    }
    Ok(bytes.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect())
}

/// Settings of the simulated detector.
#[derive(Clone, Debug, PartialEq)]
pub struct SimConfig {
    /// Fewer visible pixels than this: not detected.
    pub min_pixels: usize,
    /// Median depth beyond this (or no valid depth while the frame has depth): not detected, metres.
    pub max_range_m: f32,
    /// Probability of missing a detectable instance in a frame, 0–1.
    pub miss_rate: f32,
    /// Each box edge moves by up to ± this many pixels.
    pub jitter_px: f32,
    /// Seed of the misses and the jitter.
    pub seed: u64,
    /// Confidence reported for every simulated detection (oracle).
    pub score: f32,
    /// The measured error model (realistic); `None` is the oracle.
    pub model: Option<Arc<DetectorModel>>,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self { min_pixels: 50, max_range_m: 10.0, miss_rate: 0.0, jitter_px: 0.0, seed: 0, score: 0.9, model: None }
    }
}

/// Item numbers of false positives in the draws (instance ids are u16).
const FP_ITEM: u64 = 1 << 32;

#[derive(Default)]
struct Extent {
    x_min: u32,
    y_min: u32,
    x_max: u32,
    y_max: u32,
    pixels: usize,
    depths: Vec<u16>,
}

/// Detections in a labelled frame, by descending score then instance id.
pub fn detect(frame: &LabeledFrame, cfg: &SimConfig, filter: &DetectFilter) -> Vec<Detection> {
    if let Some(model) = &cfg.model {
        return detect_realistic(frame, cfg, model, filter);
    }
    let classes: HashMap<u32, i32> = frame
        .instances
        .iter()
        .filter(|i| i.class_id >= 0 && filter.accepts_class(i.class_id))
        .map(|i| (i.instance_id, i.class_id))
        .collect();
    if classes.is_empty() || cfg.score < filter.min_score {
        return Vec::new();
    }
    let has_depth = !frame.depth_mm.is_empty();
    let mut extents = extents_of(frame, &classes, has_depth);
    let mut ids: Vec<u32> = extents.keys().copied().collect();
    ids.sort_unstable();
    let (fw, fh) = (frame.width as f32, frame.height as f32);
    let draws = Draws::new(cfg.seed, frame.robot, frame.seq);
    let mut out = Vec::new();
    for id in ids {
        let mut e = extents.remove(&id).expect("key listed");
        if e.pixels < cfg.min_pixels.max(1) {
            continue;
        }
        if has_depth {
            if e.depths.is_empty() {
                continue;
            }
            let mid = e.depths.len() / 2;
            let median_m = *e.depths.select_nth_unstable(mid).1 as f32 / 1000.0;
            if median_m > cfg.max_range_m {
                continue;
            }
        }
        if cfg.miss_rate > 0.0 && draws.uniform(u64::from(id), 0) < cfg.miss_rate {
            continue;
        }
        let jitter = |k: u64| (draws.uniform(u64::from(id), k) * 2.0 - 1.0) * cfg.jitter_px;
        // Pixel (x, y) covers [x, x+1) × [y, y+1).
        let (mut x0, mut y0, mut x1, mut y1) =
            (e.x_min as f32, e.y_min as f32, e.x_max as f32 + 1.0, e.y_max as f32 + 1.0);
        if cfg.jitter_px > 0.0 {
            x0 = (x0 + jitter(1)).clamp(0.0, fw);
            y0 = (y0 + jitter(2)).clamp(0.0, fh);
            x1 = (x1 + jitter(3)).clamp(0.0, fw);
            y1 = (y1 + jitter(4)).clamp(0.0, fh);
            if x1 <= x0 || y1 <= y0 {
                continue;
            }
        }
        out.push(Detection { x_min: x0, y_min: y0, x_max: x1, y_max: y1, class_id: classes[&id], score: cfg.score });
    }
    out
}

/// Visible extent (and depths) of every instance in `classes`.
///
/// Instance ids are u16, so a dense table of 65,536 slots tells which ids
/// are wanted and where each one's extent is: hashing every pixel's id
/// took most of this stage's time at 640 × 480 (docs/reliability.md,
/// "Robots on one gateway").
fn extents_of(frame: &LabeledFrame, classes: &HashMap<u32, i32>, with_depth: bool) -> HashMap<u32, Extent> {
    const NONE: u32 = u32::MAX;
    let has_depth = with_depth && !frame.depth_mm.is_empty();
    let w = frame.width as usize;
    if w == 0 {
        return HashMap::new();
    }
    let mut slot = vec![NONE; 1 << 16];
    for &id in classes.keys().filter(|&&id| id != 0 && id < 1 << 16) {
        slot[id as usize] = NONE - 1;
    }
    let mut found: Vec<(u32, Extent)> = Vec::new();
    for (y, row) in frame.instance_ids.chunks(w).enumerate() {
        let y = y as u32;
        for (x, &id) in row.iter().enumerate() {
            let s = slot[id as usize];
            if s == NONE {
                continue;
            }
            let x = x as u32;
            let e = if s == NONE - 1 {
                slot[id as usize] = found.len() as u32;
                found.push((id as u32, Extent { x_min: x, y_min: y, x_max: x, y_max: y, ..Default::default() }));
                &mut found.last_mut().expect("just pushed").1
            } else {
                &mut found[s as usize].1
            };
            e.x_min = e.x_min.min(x);
            e.x_max = e.x_max.max(x);
            e.y_min = e.y_min.min(y);
            e.y_max = e.y_max.max(y);
            e.pixels += 1;
            let i = y as usize * w + x as usize;
            if has_depth && frame.depth_mm[i] > 0 {
                e.depths.push(frame.depth_mm[i]);
            }
        }
    }
    found.into_iter().collect()
}

/// The realistic detector: misses, confusions, jitter, confidences and
/// false positives drawn from the measured model.
fn detect_realistic(frame: &LabeledFrame, cfg: &SimConfig, m: &DetectorModel, filter: &DetectFilter) -> Vec<Detection> {
    let classes: HashMap<u32, i32> =
        frame.instances.iter().filter(|i| i.class_id >= 0).map(|i| (i.instance_id, i.class_id)).collect();
    let visible: HashMap<u32, f32> = frame.instances.iter().map(|i| (i.instance_id, i.visible_fraction)).collect();
    let mut extents = extents_of(frame, &classes, false);
    let mut ids: Vec<u32> = extents.keys().copied().collect();
    ids.sort_unstable();
    let (fw, fh) = (frame.width as f32, frame.height as f32);
    let to_reference = REFERENCE_HEIGHT_PX / fh.max(1.0);
    let draws = Draws::new(cfg.seed, frame.robot, frame.seq);
    let mut out = Vec::new();
    for id in ids {
        let e = extents.remove(&id).expect("key listed");
        if e.pixels < cfg.min_pixels.max(1) {
            continue;
        }
        let item = u64::from(id);
        let (x0, y0, x1, y1) = (e.x_min as f32, e.y_min as f32, e.x_max as f32 + 1.0, e.y_max as f32 + 1.0);
        let (w, h) = (x1 - x0, y1 - y0);
        let vis = visible.get(&id).copied().filter(|v| *v > 0.0).unwrap_or(1.0);
        let recall = m.recall(classes[&id], h * to_reference, vis);
        if draws.uniform(item, 0) >= recall {
            continue;
        }
        let class_id = m.confuse(classes[&id], draws.uniform(item, 1));
        let score = from_deciles(&m.tp_score, draws.uniform(item, 2));
        let j = |k: u64, size: f32| draws.normal(item, k) * m.jitter_sd * size;
        let b = Detection {
            x_min: (x0 + j(3, w)).clamp(0.0, fw),
            y_min: (y0 + j(5, h)).clamp(0.0, fh),
            x_max: (x1 + j(7, w)).clamp(0.0, fw),
            y_max: (y1 + j(9, h)).clamp(0.0, fh),
            class_id,
            score,
        };
        if b.x_max > b.x_min && b.y_max > b.y_min && filter.accepts(&b) {
            out.push(b);
        }
    }
    let n_fp = draws.poisson(FP_ITEM, m.fp_per_frame);
    for k in 0..u64::from(n_fp) {
        let item = FP_ITEM + 1 + k;
        let Some(class_id) = m.fp_class_at(draws.uniform(item, 0)) else { break };
        let h = (from_deciles(&m.fp_height_px, draws.uniform(item, 1)) / to_reference).min(fh);
        let w = (h * from_deciles(&m.fp_aspect, draws.uniform(item, 2))).min(fw);
        let x0 = draws.uniform(item, 3) * (fw - w);
        let y0 = draws.uniform(item, 4) * (fh - h);
        let b = Detection {
            x_min: x0,
            y_min: y0,
            x_max: x0 + w,
            y_max: y0 + h,
            class_id,
            score: from_deciles(&m.fp_score, draws.uniform(item, 5)),
        };
        if w >= 1.0 && h >= 1.0 && filter.accepts(&b) {
            out.push(b);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 20×10 frame: a person (id 1) at x 2..6 behind a chair (id 2) covering x 4..8,
    /// a wall (id 3, class −1) on the right, a far bicycle (id 4) and a speck (id 5).
    fn frame(seq: u64) -> LabeledFrame {
        let (w, h) = (20u32, 10u32);
        let mut ids = vec![0u16; (w * h) as usize];
        let mut depth = vec![0u16; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                let (id, d) = match (x, y) {
                    (4..=7, 3..=9) => (2, 2000),
                    (2..=5, 1..=9) => (1, 3000),
                    (17..=19, _) => (3, 1500),
                    (10..=13, 0..=4) => (4, 12000),
                    (15, 0) => (5, 1000),
                    _ => (0, 0),
                };
                ids[i] = id;
                depth[i] = d;
            }
        }
        LabeledFrame {
            robot: 0,
            seq,
            width: w,
            height: h,
            instance_ids: ids,
            instances: vec![
                Instance { instance_id: 1, class_id: 0, visible_fraction: 1.0 },
                Instance { instance_id: 2, class_id: 56, visible_fraction: 1.0 },
                Instance { instance_id: 3, class_id: -1, visible_fraction: 1.0 },
                Instance { instance_id: 4, class_id: 1, visible_fraction: 1.0 },
                Instance { instance_id: 5, class_id: 39, visible_fraction: 1.0 },
            ],
            depth_mm: depth,
        }
    }

    fn all() -> DetectFilter {
        DetectFilter { class_ids: vec![], min_score: 0.4 }
    }

    #[test]
    fn boxes_follow_visible_pixels_range_and_size() {
        let cfg = SimConfig { min_pixels: 5, ..Default::default() };
        let dets = detect(&frame(0), &cfg, &all());
        // Person: visible x 2..3 (rows 3..9, the chair hides 4..5) and x 2..5 (rows 1..2) → box x 2..6, y 1..10.
        assert_eq!(dets.len(), 2, "{dets:?}");
        let person = dets.iter().find(|d| d.class_id == 0).unwrap();
        assert_eq!((person.x_min, person.y_min, person.x_max, person.y_max), (2.0, 1.0, 6.0, 10.0));
        let chair = dets.iter().find(|d| d.class_id == 56).unwrap();
        assert_eq!((chair.x_min, chair.y_min, chair.x_max, chair.y_max), (4.0, 3.0, 8.0, 10.0));
        // The bicycle at 12 m is beyond the default 10 m; with 15 m it is seen.
        let far = SimConfig { max_range_m: 15.0, ..cfg.clone() };
        assert!(detect(&frame(0), &far, &all()).iter().any(|d| d.class_id == 1));
        // Without depth there is no range check; the one-pixel bottle stays below min_pixels.
        let mut no_depth = frame(0);
        no_depth.depth_mm.clear();
        let classes: Vec<i32> = detect(&no_depth, &cfg, &all()).iter().map(|d| d.class_id).collect();
        assert_eq!(classes, vec![0, 56, 1]);
        // Class filter and a min score above the simulated confidence.
        let chairs = DetectFilter { class_ids: vec![56], min_score: 0.4 };
        assert_eq!(detect(&frame(0), &cfg, &chairs).len(), 1);
        assert!(detect(&frame(0), &cfg, &DetectFilter { class_ids: vec![], min_score: 0.95 }).is_empty());
    }

    #[test]
    fn misses_and_jitter_are_deterministic_per_seed_seq_and_instance() {
        let cfg = SimConfig { min_pixels: 5, miss_rate: 0.5, jitter_px: 2.0, seed: 7, ..Default::default() };
        let runs: Vec<Vec<Detection>> = (0..200).map(|seq| detect(&frame(seq), &cfg, &all())).collect();
        let again: Vec<Vec<Detection>> = (0..200).map(|seq| detect(&frame(seq), &cfg, &all())).collect();
        assert_eq!(runs, again);
        let seen: usize = runs.iter().map(|d| d.len()).sum();
        // 400 chances at a 50 % miss rate.
        assert!((140..=260).contains(&seen), "{seen}");
        // Jitter stays within ±2 px and actually moves boxes.
        let persons: Vec<&Detection> = runs.iter().flatten().filter(|d| d.class_id == 0).collect();
        assert!(persons.iter().all(|d| (d.x_min - 2.0).abs() <= 2.0 && (d.y_max - 10.0).abs() <= 2.0));
        assert!(persons.iter().any(|d| d.x_min != 2.0));
        let other_seed = SimConfig { seed: 8, ..cfg };
        let differ = (0..200).any(|seq| detect(&frame(seq), &other_seed, &all()) != runs[seq as usize]);
        assert!(differ);
    }

    #[test]
    fn parse_checks_lengths() {
        assert_eq!(parse_u16_image("instance_ids", 2, 1, &[1, 0, 0, 1]).unwrap(), vec![1, 256]);
        let e = parse_u16_image("instance_ids", 2, 2, &[1, 0, 0, 1]).unwrap_err();
        assert!(e.to_string().contains("expected 8"), "{e}");
        // A declared size whose byte count overflows is refused, not a panic.
        assert!(parse_u16_image("instance_ids", u32::MAX, u32::MAX, &[0; 4]).is_err());
    }

    use crate::error_model::Profile;

    /// A 160×120 frame with one instance of `class_id`, `h` pixels tall
    /// (a third as wide), `visible` of it in view.
    fn one_object(seq: u64, robot: u64, class_id: i32, h: u32, visible: f32) -> LabeledFrame {
        let (w, fh) = (160u32, 120u32);
        let mut ids = vec![0u16; (w * fh) as usize];
        let bw = (h / 3).max(1);
        for y in 10..10 + h {
            for x in 60..60 + bw {
                ids[(y * w + x) as usize] = 1;
            }
        }
        LabeledFrame {
            robot,
            seq,
            width: w,
            height: fh,
            instance_ids: ids,
            instances: vec![Instance { instance_id: 1, class_id, visible_fraction: visible }],
            depth_mm: Vec::new(),
        }
    }

    /// The true box of [`one_object`].
    fn truth(h: u32) -> Detection {
        Detection {
            x_min: 60.0,
            y_min: 10.0,
            x_max: 60.0 + (h / 3).max(1) as f32,
            y_max: 10.0 + h as f32,
            class_id: 0,
            score: 1.0,
        }
    }

    fn realistic(seed: u64) -> SimConfig {
        SimConfig { min_pixels: 1, seed, model: Some(Arc::new(Profile::nanodet().detector)), ..Default::default() }
    }

    const N: u64 = 4000;

    /// Tolerance of a rate measured over N trials: five binomial standard deviations.
    fn tol(p: f32) -> f32 {
        5.0 * (p * (1.0 - p) / N as f32).sqrt() + 1e-3
    }

    #[test]
    fn realistic_misses_follow_the_calibrated_recall_by_height_and_visibility() {
        let cfg = realistic(11);
        let m = cfg.model.clone().unwrap();
        let any = DetectFilter { class_ids: vec![], min_score: 0.0 };
        for (h, vis) in [(4u32, 1.0f32), (8, 1.0), (16, 1.0), (40, 1.0), (40, 0.5), (16, 0.3)] {
            let expected = m.recall(0, h as f32 * REFERENCE_HEIGHT_PX / 120.0, vis);
            let found = (0..N)
                .filter(|&seq| {
                    detect(&one_object(seq, 5, 0, h, vis), &cfg, &any).iter().any(|d| d.iou(&truth(h)) > 0.3)
                })
                .count() as f32
                / N as f32;
            assert!(
                (found - expected).abs() <= tol(expected) + 0.01,
                "{h} px ({} px at 480), visible {vis}: found {found:.3}, calibrated {expected:.3}",
                h * 4
            );
        }
        // Recall rises with size and falls with occlusion.
        assert!(m.recall(0, 16.0, 1.0) <= m.recall(0, 160.0, 1.0));
        assert!(m.recall(0, 160.0, 0.3) <= m.recall(0, 160.0, 1.0));
    }

    #[test]
    fn realistic_false_positives_come_at_the_calibrated_rate_classes_and_sizes() {
        let cfg = realistic(12);
        let m = cfg.model.clone().unwrap();
        let any = DetectFilter { class_ids: vec![], min_score: 0.0 };
        let mut empty = one_object(0, 7, 0, 1, 1.0);
        empty.instance_ids.iter_mut().for_each(|i| *i = 0);
        empty.instances.clear();
        let mut fps = Vec::new();
        for seq in 0..N {
            empty.seq = seq;
            fps.extend(detect(&empty, &cfg, &any));
        }
        let rate = fps.len() as f32 / N as f32;
        let sd = (m.fp_per_frame / N as f32).sqrt();
        assert!((rate - m.fp_per_frame).abs() <= 5.0 * sd + 0.01, "{rate} per frame, calibrated {}", m.fp_per_frame);
        if m.fp_per_frame > 0.0 {
            let top = m.fp_class.iter().max_by(|a, b| a.share.total_cmp(&b.share)).unwrap();
            let share = fps.iter().filter(|d| d.class_id == top.class_id).count() as f32 / fps.len() as f32;
            assert!((share - top.share).abs() < 0.08, "class {} share {share}, calibrated {}", top.class_id, top.share);
            assert!(fps.iter().all(|d| d.x_min >= 0.0 && d.y_min >= 0.0 && d.x_max <= 160.0 && d.y_max <= 120.0));
            assert!(fps.iter().all(|d| d.score >= m.fp_score[0] && d.score <= m.fp_score[10]));
        }
        // A filter on a class keeps only that class's false positives.
        let chairs = DetectFilter { class_ids: vec![56], min_score: 0.0 };
        assert!(
            (0..200).flat_map(|seq| detect(&one_object(seq, 7, 0, 1, 1.0), &cfg, &chairs)).all(|d| d.class_id == 56)
        );
    }

    #[test]
    fn realistic_confusions_come_at_the_calibrated_rate() {
        let cfg = realistic(13);
        let m = cfg.model.clone().unwrap();
        let any = DetectFilter { class_ids: vec![], min_score: 0.0 };
        // A measured class with confusions, else an unmeasured one (the pooled rate to its confusable class).
        let (class, rate) = m
            .class
            .iter()
            .map(|c| (c.class_id, c.confusion.iter().map(|x| x.rate).sum::<f32>()))
            .filter(|(_, r)| *r > 0.0)
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((56, m.confusion_rate_all));
        let (mut hits, mut confused) = (0u32, 0u32);
        for seq in 0..N {
            for d in detect(&one_object(seq, 9, class, 100, 1.0), &cfg, &any) {
                if d.iou(&truth(100)) > 0.5 {
                    hits += 1;
                    confused += u32::from(d.class_id != class);
                }
            }
        }
        let measured = confused as f32 / hits.max(1) as f32;
        assert!(hits > 1000, "{hits}");
        assert!(
            (measured - rate).abs() <= tol(rate) * 2.0 + 0.01,
            "class {class}: {measured:.3} vs calibrated {rate:.3}"
        );
    }

    #[test]
    fn realistic_boxes_jitter_by_the_calibrated_spread_and_scores_follow_the_deciles() {
        let cfg = realistic(14);
        let m = cfg.model.clone().unwrap();
        let any = DetectFilter { class_ids: vec![0], min_score: 0.0 };
        let mut left = Vec::new();
        let mut scores = Vec::new();
        for seq in 0..N {
            for d in detect(&one_object(seq, 3, 0, 90, 1.0), &cfg, &any) {
                if d.iou(&truth(90)) > 0.5 {
                    left.push((d.x_min - 60.0) / 30.0);
                    scores.push(d.score);
                }
            }
        }
        let sd = (left.iter().map(|x| x * x).sum::<f32>() / left.len() as f32).sqrt();
        assert!((sd - m.jitter_sd).abs() < 0.2 * m.jitter_sd + 0.01, "edge sd {sd}, calibrated {}", m.jitter_sd);
        scores.sort_by(f32::total_cmp);
        let median = scores[scores.len() / 2];
        assert!((median - m.tp_score[5]).abs() < 0.03, "median score {median}, calibrated {}", m.tp_score[5]);
    }

    #[test]
    fn realistic_draws_depend_on_seed_robot_and_frame_only() {
        let cfg = realistic(15);
        let any = DetectFilter { class_ids: vec![], min_score: 0.0 };
        let run = |robot: u64, cfg: &SimConfig| -> Vec<Vec<Detection>> {
            (0..300).map(|seq| detect(&one_object(seq, robot, 0, 12, 1.0), cfg, &any)).collect()
        };
        assert_eq!(run(1, &cfg), run(1, &cfg));
        assert_ne!(run(1, &cfg), run(2, &cfg), "another robot draws other errors");
        assert_ne!(run(1, &cfg), run(1, &realistic(16)), "another seed too");
    }
}
