//! Backend-independent detection logic: the detection type, letterbox
//! geometry, dense-head decoding (distribution boxes as NanoDet and YOLOv8
//! predict them) and class-aware non-maximum suppression. Plain Rust, no
//! tensors, no proto.

/// One detected object, in pixels of the image it was detected in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Detection {
    pub x_min: f32,
    pub y_min: f32,
    pub x_max: f32,
    pub y_max: f32,
    /// COCO-80 class index as YOLOv8 numbers it.
    pub class_id: i32,
    pub score: f32,
}

impl Detection {
    pub fn width(&self) -> f32 {
        (self.x_max - self.x_min).max(0.0)
    }

    pub fn height(&self) -> f32 {
        (self.y_max - self.y_min).max(0.0)
    }

    pub fn area(&self) -> f32 {
        self.width() * self.height()
    }

    /// Intersection over union of two boxes (0 when either is empty).
    pub fn iou(&self, other: &Detection) -> f32 {
        let iw = (self.x_max.min(other.x_max) - self.x_min.max(other.x_min)).max(0.0);
        let ih = (self.y_max.min(other.y_max) - self.y_min.max(other.y_min)).max(0.0);
        let inter = iw * ih;
        let union = self.area() + other.area() - inter;
        if union <= 0.0 { 0.0 } else { inter / union }
    }
}

/// What a caller wants back: which classes, how confident.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectFilter {
    /// Only these classes; empty means all.
    pub class_ids: Vec<i32>,
    /// Minimum confidence.
    pub min_score: f32,
}

impl DetectFilter {
    pub fn accepts_class(&self, class_id: i32) -> bool {
        self.class_ids.is_empty() || self.class_ids.contains(&class_id)
    }

    pub fn accepts(&self, d: &Detection) -> bool {
        d.score >= self.min_score && self.accepts_class(d.class_id)
    }
}

/// Aspect-preserving resize of a `src_w`×`src_h` image into a square
/// `size`×`size` network input, centred, the rest padded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Letterbox {
    pub src_w: u32,
    pub src_h: u32,
    pub size: u32,
    /// Network pixels per source pixel.
    pub scale: f32,
    /// Size of the resized image inside the canvas.
    pub new_w: u32,
    pub new_h: u32,
    /// Offset of the resized image in the canvas.
    pub pad_x: u32,
    pub pad_y: u32,
}

impl Letterbox {
    pub fn new(src_w: u32, src_h: u32, size: u32) -> Self {
        let scale = (size as f32 / src_w.max(1) as f32).min(size as f32 / src_h.max(1) as f32);
        let new_w = ((src_w as f32 * scale).round() as u32).clamp(1, size);
        let new_h = ((src_h as f32 * scale).round() as u32).clamp(1, size);
        let pad_x = (size - new_w) / 2;
        let pad_y = (size - new_h) / 2;
        Self { src_w, src_h, size, scale, new_w, new_h, pad_x, pad_y }
    }

    /// Maps a box from network-input pixels back to source pixels, clipped to the image.
    pub fn to_source(&self, d: Detection) -> Detection {
        let sx = self.new_w as f32 / self.src_w.max(1) as f32;
        let sy = self.new_h as f32 / self.src_h.max(1) as f32;
        let (w, h) = (self.src_w as f32, self.src_h as f32);
        Detection {
            x_min: ((d.x_min - self.pad_x as f32) / sx).clamp(0.0, w),
            y_min: ((d.y_min - self.pad_y as f32) / sy).clamp(0.0, h),
            x_max: ((d.x_max - self.pad_x as f32) / sx).clamp(0.0, w),
            y_max: ((d.y_max - self.pad_y as f32) / sy).clamp(0.0, h),
            ..d
        }
    }
}

/// One pyramid level of a dense anchor-free head, point-major: point
/// `i = y·width + x` has its centre at ((x+0.5)·stride, (y+0.5)·stride).
#[derive(Clone, Copy, Debug)]
pub struct HeadLevel<'a> {
    pub stride: f32,
    pub width: usize,
    pub height: usize,
    /// Class probabilities, `[points][num_classes]`.
    pub scores: &'a [f32],
    /// Box side distributions (left, top, right, bottom) as logits,
    /// `[points][4][bins]`.
    pub box_logits: &'a [f32],
}

/// Shape of a dense head's outputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeadSpec {
    pub num_classes: usize,
    /// Bins of each side's distance distribution (NanoDet 11, YOLOv8 16).
    pub bins: usize,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DecodeError {
    #[error("head level with stride {stride}: {what} has {got} values, expected {expected}")]
    Shape { stride: f32, what: &'static str, got: usize, expected: usize },
}

/// Expected distance of one side: Σ softmax(logits)_i · i.
pub fn expected_bin(logits: &[f32]) -> f32 {
    let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let (mut num, mut den) = (0.0f32, 0.0f32);
    for (i, &l) in logits.iter().enumerate() {
        let e = (l - max).exp();
        num += e * i as f32;
        den += e;
    }
    num / den
}

/// Decodes dense head outputs into boxes in network-input pixels: for each
/// point the best class (if it passes `filter`) and the box from the four
/// side distributions, each the softmax expectation times the stride.
pub fn decode_dense(
    levels: &[HeadLevel<'_>],
    spec: HeadSpec,
    filter: &DetectFilter,
) -> Result<Vec<Detection>, DecodeError> {
    let mut out = Vec::new();
    let nc = spec.num_classes;
    let nb = 4 * spec.bins;
    for level in levels {
        let points = level.width * level.height;
        if level.scores.len() != points * nc {
            return Err(DecodeError::Shape {
                stride: level.stride,
                what: "class scores",
                got: level.scores.len(),
                expected: points * nc,
            });
        }
        if level.box_logits.len() != points * nb {
            return Err(DecodeError::Shape {
                stride: level.stride,
                what: "box distributions",
                got: level.box_logits.len(),
                expected: points * nb,
            });
        }
        for p in 0..points {
            let scores = &level.scores[p * nc..(p + 1) * nc];
            let mut best: Option<(usize, f32)> = None;
            for (c, &s) in scores.iter().enumerate() {
                if s >= filter.min_score && filter.accepts_class(c as i32) && best.is_none_or(|(_, b)| s > b) {
                    best = Some((c, s));
                }
            }
            let Some((class, score)) = best else { continue };
            let dist = &level.box_logits[p * nb..(p + 1) * nb];
            let side = |k: usize| expected_bin(&dist[k * spec.bins..(k + 1) * spec.bins]) * level.stride;
            let cx = ((p % level.width) as f32 + 0.5) * level.stride;
            let cy = ((p / level.width) as f32 + 0.5) * level.stride;
            out.push(Detection {
                x_min: cx - side(0),
                y_min: cy - side(1),
                x_max: cx + side(2),
                y_max: cy + side(3),
                class_id: class as i32,
                score,
            });
        }
    }
    Ok(out)
}

/// Class-aware non-maximum suppression: highest score first; a box is dropped
/// when it overlaps a kept box of the same class by more than `iou_threshold`.
/// Returns at most `max_detections` boxes, by descending score.
pub fn nms(mut dets: Vec<Detection>, iou_threshold: f32, max_detections: usize) -> Vec<Detection> {
    dets.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept: Vec<Detection> = Vec::new();
    for d in dets {
        if kept.len() >= max_detections {
            break;
        }
        if kept.iter().all(|k| k.class_id != d.class_id || k.iou(&d) <= iou_threshold) {
            kept.push(d);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(x0: f32, y0: f32, x1: f32, y1: f32, class_id: i32, score: f32) -> Detection {
        Detection { x_min: x0, y_min: y0, x_max: x1, y_max: y1, class_id, score }
    }

    #[test]
    fn iou_of_known_overlaps() {
        let a = det(0.0, 0.0, 10.0, 10.0, 0, 1.0);
        assert_eq!(a.iou(&a), 1.0);
        let b = det(5.0, 0.0, 15.0, 10.0, 0, 1.0);
        assert!((a.iou(&b) - 50.0 / 150.0).abs() < 1e-6);
        let c = det(20.0, 20.0, 30.0, 30.0, 0, 1.0);
        assert_eq!(a.iou(&c), 0.0);
        let empty = det(3.0, 3.0, 3.0, 3.0, 0, 1.0);
        assert_eq!(empty.iou(&empty), 0.0);
    }

    #[test]
    fn nms_is_class_aware_and_ordered() {
        let dets = vec![
            det(0.0, 0.0, 10.0, 10.0, 0, 0.6),
            det(1.0, 1.0, 11.0, 11.0, 0, 0.9), // same class, overlaps: keeps the 0.9
            det(1.0, 1.0, 11.0, 11.0, 1, 0.5), // other class: kept
            det(50.0, 50.0, 60.0, 60.0, 0, 0.7),
        ];
        let kept = nms(dets, 0.45, 100);
        let scores: Vec<f32> = kept.iter().map(|d| d.score).collect();
        assert_eq!(scores, vec![0.9, 0.7, 0.5]);
        assert_eq!(kept[2].class_id, 1);
        assert_eq!(nms(kept.clone(), 0.45, 2).len(), 2);
    }

    #[test]
    fn letterbox_maps_boxes_back() {
        let lb = Letterbox::new(640, 480, 416);
        assert_eq!((lb.new_w, lb.new_h, lb.pad_x, lb.pad_y), (416, 312, 0, 52));
        // Source box (100, 200)–(300, 400) in network pixels is scaled by 0.65 and shifted by 52 in y.
        let net = det(65.0, 130.0 + 52.0, 195.0, 260.0 + 52.0, 3, 0.5);
        let src = lb.to_source(net);
        assert!((src.x_min - 100.0).abs() < 1e-3 && (src.y_min - 200.0).abs() < 1e-3);
        assert!((src.x_max - 300.0).abs() < 1e-3 && (src.y_max - 400.0).abs() < 1e-3);
        // Boxes reaching into the padding are clipped to the image.
        let clipped = lb.to_source(det(-10.0, 0.0, 500.0, 416.0, 0, 0.5));
        assert_eq!((clipped.x_min, clipped.y_min, clipped.x_max, clipped.y_max), (0.0, 0.0, 640.0, 480.0));
        let tall = Letterbox::new(300, 600, 640);
        assert_eq!((tall.new_w, tall.new_h, tall.pad_x, tall.pad_y), (320, 640, 160, 0));
    }

    /// Logits that put all mass of a side's distribution on `bin`.
    fn one_hot(bins: usize, bin: usize) -> Vec<f32> {
        (0..bins).map(|i| if i == bin { 30.0 } else { -30.0 }).collect()
    }

    #[test]
    fn decodes_a_constructed_head() {
        // A 4×3 level at stride 8 with 3 classes and 5 bins; one confident point at (x=2, y=1).
        let (w, h, nc, bins) = (4usize, 3usize, 3usize, 5usize);
        let mut scores = vec![0.01f32; w * h * nc];
        let mut logits = vec![0.0f32; w * h * 4 * bins];
        let p = w + 2;
        scores[p * nc + 2] = 0.8;
        for (k, bin) in [1usize, 2, 3, 4].into_iter().enumerate() {
            logits[p * 4 * bins + k * bins..p * 4 * bins + (k + 1) * bins].copy_from_slice(&one_hot(bins, bin));
        }
        let level = HeadLevel { stride: 8.0, width: w, height: h, scores: &scores, box_logits: &logits };
        let spec = HeadSpec { num_classes: nc, bins };
        let filter = DetectFilter { class_ids: vec![], min_score: 0.5 };
        let dets = decode_dense(&[level], spec, &filter).unwrap();
        assert_eq!(dets.len(), 1);
        let d = dets[0];
        // Centre (2.5·8, 1.5·8) = (20, 12); sides 1, 2, 3, 4 bins × 8 px.
        assert_eq!(d.class_id, 2);
        assert!((d.x_min - 12.0).abs() < 1e-3, "{d:?}");
        assert!((d.y_min - -4.0).abs() < 1e-3, "{d:?}");
        assert!((d.x_max - 44.0).abs() < 1e-3, "{d:?}");
        assert!((d.y_max - 44.0).abs() < 1e-3, "{d:?}");
        // A uniform distribution decodes to the mean bin.
        assert!((expected_bin(&[0.0; 5]) - 2.0).abs() < 1e-6);
        // Class filtering drops it; a wrong shape is an error, not a panic.
        let only_person = DetectFilter { class_ids: vec![0], min_score: 0.5 };
        assert!(decode_dense(&[level], spec, &only_person).unwrap().is_empty());
        let bad = HeadLevel { scores: &scores[1..], ..level };
        assert!(matches!(decode_dense(&[bad], spec, &filter), Err(DecodeError::Shape { what: "class scores", .. })));
    }
}
