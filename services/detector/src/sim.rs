//! The simulation backend: detections read from the simulator's label image
//! (per-pixel instance ids) instead of a network. An instance is detected
//! when its class is a COCO class, enough of it is visible (occlusion is
//! already in the label image: hidden pixels belong to the occluder) and it is
//! within range by its median depth. Optional misses and box jitter are
//! deterministic functions of (seed, frame seq, instance id), so simulated
//! runs reproduce exactly.

use std::collections::HashMap;

use crate::detection::{DetectFilter, Detection};

/// One entry of the label image's instance table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Instance {
    pub instance_id: u32,
    /// COCO-80 class id, or −1 for structure and floor.
    pub class_id: i32,
}

/// A label image with its aligned depth.
#[derive(Clone, Debug, PartialEq)]
pub struct LabeledFrame {
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
    let expected = width as usize * height as usize * 2;
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
    /// Confidence reported for every simulated detection.
    pub score: f32,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self { min_pixels: 50, max_range_m: 10.0, miss_rate: 0.0, jitter_px: 0.0, seed: 0, score: 0.9 }
    }
}

/// SplitMix64: a good 64-bit mix for counter-based random numbers.
fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The `k`-th uniform number in [0, 1) for (seed, seq, instance).
fn uniform(seed: u64, seq: u64, instance: u32, k: u64) -> f32 {
    let h = splitmix(splitmix(splitmix(seed) ^ seq) ^ ((instance as u64) << 8 | k));
    (h >> 40) as f32 / (1u64 << 24) as f32
}

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
    let mut extents: HashMap<u32, Extent> = HashMap::new();
    let w = frame.width as usize;
    for (i, &id) in frame.instance_ids.iter().enumerate() {
        if id == 0 || !classes.contains_key(&(id as u32)) {
            continue;
        }
        let (x, y) = ((i % w) as u32, (i / w) as u32);
        let e = extents.entry(id as u32).or_insert_with(|| Extent {
            x_min: x,
            y_min: y,
            x_max: x,
            y_max: y,
            ..Default::default()
        });
        e.x_min = e.x_min.min(x);
        e.x_max = e.x_max.max(x);
        e.y_min = e.y_min.min(y);
        e.y_max = e.y_max.max(y);
        e.pixels += 1;
        if has_depth && frame.depth_mm[i] > 0 {
            e.depths.push(frame.depth_mm[i]);
        }
    }
    let mut ids: Vec<u32> = extents.keys().copied().collect();
    ids.sort_unstable();
    let (fw, fh) = (frame.width as f32, frame.height as f32);
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
        if cfg.miss_rate > 0.0 && uniform(cfg.seed, frame.seq, id, 0) < cfg.miss_rate {
            continue;
        }
        let jitter = |k: u64| (uniform(cfg.seed, frame.seq, id, k) * 2.0 - 1.0) * cfg.jitter_px;
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
            seq,
            width: w,
            height: h,
            instance_ids: ids,
            instances: vec![
                Instance { instance_id: 1, class_id: 0 },
                Instance { instance_id: 2, class_id: 56 },
                Instance { instance_id: 3, class_id: -1 },
                Instance { instance_id: 4, class_id: 1 },
                Instance { instance_id: 5, class_id: 39 },
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
    }
}
