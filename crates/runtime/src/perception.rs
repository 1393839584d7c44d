//! The perception error model of the simulation backends: what a real
//! detector and a real ReID embedder would have made of what the
//! simulator's label image shows.
//!
//! Its parameters are a *profile* measured by `vlnav calibrate-perception`
//! (the real NanoDet on the registry's real photos, scaled, cropped and
//! pasted on other backgrounds) and committed as
//! `deploy/perception/nanodet-realistic.toml`:
//! - per-class recall as a function of the box's apparent height (pixels of
//!   a 640×480 frame, the D455 colour stream the paper used) and of the
//!   instance's visible (unoccluded, untruncated) fraction;
//! - class confusion (a detection labelled as another class);
//! - box jitter (each edge moves by a normal share of the box's size);
//! - the confidence of true detections and of false positives;
//! - false positives per frame: their classes, heights, aspect ratios.
//!
//! Every draw is a pure function of (seed, robot, frame seq, instance, k),
//! so a run reproduces bit for bit however requests interleave.

use serde::{Deserialize, Serialize};

/// How the simulated robot's frames are perceived (`--perception` of
/// `vlnav up` and `vlnav eval`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PerceptionMode {
    /// Ground truth: every visible instance with its exact box, true
    /// identities, the label image's no-go mask (an upper bound).
    Oracle,
    /// The measured error model of the shipped NanoDet and MobileNetV2 on
    /// the label image, and the real colour + depth segmenter on the
    /// rendered RGB-D frames.
    #[default]
    Realistic,
    /// The real NanoDet, MobileNetV2 and segmenter on the rendered frames (slow on CPU).
    Neural,
}

impl PerceptionMode {
    pub fn as_str(self) -> &'static str {
        match self {
            PerceptionMode::Oracle => "oracle",
            PerceptionMode::Realistic => "realistic",
            PerceptionMode::Neural => "neural",
        }
    }
}

impl std::fmt::Display for PerceptionMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The profile shipped for the default detector (NanoDet, real COCO weights).
pub const NANODET_REALISTIC: &str = include_str!("../../../deploy/perception/nanodet-realistic.toml");

/// Heights in a profile are pixels of a frame this tall (the D455's 640×480
/// colour stream); a frame of another size is scaled to it.
pub const REFERENCE_HEIGHT_PX: f32 = 480.0;

/// Where the numbers came from.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    pub tool: String,
    pub detector: String,
    #[serde(default)]
    pub weights_sha256: String,
    #[serde(default)]
    pub reid_model: String,
    #[serde(default)]
    pub photos: Vec<String>,
    pub date: String,
    #[serde(default)]
    pub canvases: u32,
    #[serde(default)]
    pub objects: u32,
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub notes: String,
}

/// One class's measured recall curve and confusions.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ClassModel {
    pub class_id: i32,
    #[serde(default)]
    pub name: String,
    /// Objects measured per height bin.
    pub samples: Vec<u32>,
    /// Recall per height bin at full visibility (bins with fewer than
    /// [`MIN_SAMPLES`] samples fall back to the pooled curve).
    pub recall: Vec<f32>,
    /// Share of this class's detections that came out as another class.
    #[serde(default)]
    pub confusion: Vec<Confusion>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Confusion {
    /// The class reported instead.
    pub to: i32,
    /// Probability of a detection of this class being reported as `to`.
    pub rate: f32,
}

/// A false positive class and its share of all false positives.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FpClass {
    pub class_id: i32,
    pub share: f32,
}

/// The detector's error model.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DetectorModel {
    /// The confidence threshold the rates were measured at.
    pub min_score: f32,
    /// IoU with the reference box for a detection to count as a hit.
    pub iou_match: f32,
    /// Centres of the height bins, pixels of a 640×480 frame, ascending.
    pub height_px: Vec<f32>,
    /// Recall per height bin pooled over every class (full visibility).
    pub recall_all: Vec<f32>,
    /// Visible fractions measured, ascending, ending at 1.
    pub visible_fraction: Vec<f32>,
    /// Recall at each visible fraction relative to full visibility (pooled).
    pub visibility_factor: Vec<f32>,
    /// Confusion rate of classes the photos do not show.
    pub confusion_rate_all: f32,
    /// Standard deviation of each box edge, as a share of the box's width
    /// (left, right) or height (top, bottom).
    pub jitter_sd: f32,
    /// IoU of hits with their reference box (reported, not drawn).
    pub iou_mean: f32,
    pub iou_sd: f32,
    /// Deciles (11 values, 0 … 1) of true detections' confidence.
    pub tp_score: Vec<f32>,
    /// Mean false positives per frame.
    pub fp_per_frame: f32,
    /// Deciles of false positives' confidence, height (px of 640×480) and width / height.
    pub fp_score: Vec<f32>,
    pub fp_height_px: Vec<f32>,
    pub fp_aspect: Vec<f32>,
    #[serde(default)]
    pub fp_class: Vec<FpClass>,
    #[serde(default)]
    pub class: Vec<ClassModel>,
}

/// The ReID model: similarities of the shipped embedder between crops of the
/// same person and of different people.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ReidModel {
    pub model: String,
    /// The service's match threshold for this embedder.
    pub threshold: f32,
    /// Deciles (11 values) of same-person and different-people similarity.
    pub same: Vec<f32>,
    pub different: Vec<f32>,
    pub same_pairs: u32,
    pub different_pairs: u32,
}

/// A whole profile file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Profile {
    pub version: u32,
    pub provenance: Provenance,
    pub detector: DetectorModel,
    #[serde(default)]
    pub reid: Option<ReidModel>,
}

/// Bins with fewer samples than this use the pooled recall.
pub const MIN_SAMPLES: u32 = 6;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ProfileError {
    #[error("perception profile: {0}")]
    Parse(String),
    #[error("perception profile: {field}: {message}")]
    Invalid { field: String, message: String },
}

fn invalid(field: impl Into<String>, message: impl Into<String>) -> ProfileError {
    ProfileError::Invalid { field: field.into(), message: message.into() }
}

fn check_unit(field: &str, xs: &[f32]) -> Result<(), ProfileError> {
    if xs.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)) {
        Ok(())
    } else {
        Err(invalid(field, "every value must be within [0, 1]"))
    }
}

fn check_deciles(field: &str, xs: &[f32]) -> Result<(), ProfileError> {
    if xs.len() != 11 {
        return Err(invalid(field, format!("needs 11 deciles (0, 0.1, … 1), got {}", xs.len())));
    }
    if !xs.iter().all(|v| v.is_finite()) || xs.windows(2).any(|w| w[1] < w[0]) {
        return Err(invalid(field, "deciles must be finite and ascending"));
    }
    Ok(())
}

impl Profile {
    pub fn parse(text: &str) -> Result<Profile, ProfileError> {
        let p: Profile = toml::from_str(text).map_err(|e| ProfileError::Parse(e.to_string()))?;
        p.validate()?;
        Ok(p)
    }

    /// The shipped NanoDet profile.
    pub fn nanodet() -> Profile {
        Profile::parse(NANODET_REALISTIC).expect("the shipped profile is valid (checked by a test)")
    }

    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a profile serialises")
    }

    pub fn validate(&self) -> Result<(), ProfileError> {
        if self.version != 1 {
            return Err(invalid("version", format!("{} is not supported (expected 1)", self.version)));
        }
        let d = &self.detector;
        let n = d.height_px.len();
        if n == 0 || d.height_px.windows(2).any(|w| w[1] <= w[0]) || d.height_px[0] <= 0.0 {
            return Err(invalid("detector.height_px", "must be positive and strictly ascending"));
        }
        if d.recall_all.len() != n {
            return Err(invalid("detector.recall_all", format!("needs one value per height bin ({n})")));
        }
        check_unit("detector.recall_all", &d.recall_all)?;
        if d.visible_fraction.is_empty()
            || d.visible_fraction.len() != d.visibility_factor.len()
            || d.visible_fraction.windows(2).any(|w| w[1] <= w[0])
        {
            return Err(invalid(
                "detector.visible_fraction",
                "ascending, with one visibility_factor per visible fraction",
            ));
        }
        check_unit("detector.visible_fraction", &d.visible_fraction)?;
        if !d.visibility_factor.iter().all(|v| v.is_finite() && *v >= 0.0) {
            return Err(invalid("detector.visibility_factor", "must be finite and ≥ 0"));
        }
        check_unit("detector.min_score", &[d.min_score, d.iou_match, d.confusion_rate_all])?;
        if !(d.jitter_sd.is_finite() && (0.0..0.5).contains(&d.jitter_sd)) {
            return Err(invalid("detector.jitter_sd", "must be within [0, 0.5)"));
        }
        if !(d.fp_per_frame.is_finite() && (0.0..=20.0).contains(&d.fp_per_frame)) {
            return Err(invalid("detector.fp_per_frame", "must be within [0, 20]"));
        }
        check_deciles("detector.tp_score", &d.tp_score)?;
        check_deciles("detector.fp_score", &d.fp_score)?;
        check_deciles("detector.fp_height_px", &d.fp_height_px)?;
        check_deciles("detector.fp_aspect", &d.fp_aspect)?;
        check_unit("detector.tp_score", &d.tp_score)?;
        check_unit("detector.fp_score", &d.fp_score)?;
        if d.fp_height_px[0] <= 0.0 || d.fp_aspect[0] <= 0.0 {
            return Err(invalid("detector.fp_height_px", "sizes must be positive"));
        }
        for (i, c) in d.class.iter().enumerate() {
            if c.samples.len() != n || c.recall.len() != n {
                return Err(invalid(format!("detector.class[{i}]"), format!("needs samples and recall per bin ({n})")));
            }
            check_unit(&format!("detector.class[{i}].recall"), &c.recall)?;
            let total: f32 = c.confusion.iter().map(|x| x.rate).sum();
            if !(0.0..=1.0).contains(&total) {
                return Err(invalid(format!("detector.class[{i}].confusion"), "rates must sum to at most 1"));
            }
        }
        if let Some(r) = &self.reid {
            check_deciles("reid.same", &r.same)?;
            check_deciles("reid.different", &r.different)?;
        }
        Ok(())
    }
}

/// SplitMix64: a good 64-bit mix for counter-based random numbers.
pub fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// FNV-1a of a string (a robot id), for seeding.
pub fn hash_str(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

/// Counter-based uniform numbers for one (seed, robot, frame).
#[derive(Clone, Copy, Debug)]
pub struct Draws {
    key: u64,
}

impl Draws {
    pub fn new(seed: u64, robot: u64, seq: u64) -> Self {
        Self { key: splitmix(splitmix(splitmix(seed) ^ robot) ^ seq) }
    }

    /// The `k`-th uniform number in [0, 1) of `item`.
    pub fn uniform(&self, item: u64, k: u64) -> f32 {
        let h = splitmix(self.key ^ splitmix(item.wrapping_mul(0x100) | k));
        (h >> 40) as f32 / (1u64 << 24) as f32
    }

    /// A standard normal number (Box–Muller on two uniforms).
    pub fn normal(&self, item: u64, k: u64) -> f32 {
        let u1 = self.uniform(item, k).max(1e-7);
        let u2 = self.uniform(item, k + 1);
        (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
    }

    /// A Poisson count with mean `lambda` (Knuth; lambda is small here).
    pub fn poisson(&self, item: u64, lambda: f32) -> u32 {
        if lambda <= 0.0 {
            return 0;
        }
        let l = (-lambda).exp();
        let mut p = 1.0f32;
        let mut k = 0u32;
        loop {
            p *= self.uniform(item, 64 + u64::from(k));
            if p <= l || k >= 50 {
                return k;
            }
            k += 1;
        }
    }
}

/// A value from deciles (inverse CDF, linear between deciles).
pub fn from_deciles(deciles: &[f32], u: f32) -> f32 {
    let x = u.clamp(0.0, 1.0) * (deciles.len() - 1) as f32;
    let i = (x.floor() as usize).min(deciles.len() - 2);
    let f = x - i as f32;
    deciles[i] + (deciles[i + 1] - deciles[i]) * f
}

/// The deciles (0, 0.1, … 1) of `xs`; empty input gives zeros.
pub fn deciles(xs: &[f32]) -> Vec<f32> {
    if xs.is_empty() {
        return vec![0.0; 11];
    }
    let mut s: Vec<f32> = xs.to_vec();
    s.sort_by(f32::total_cmp);
    (0..=10)
        .map(|k| {
            let x = k as f32 / 10.0 * (s.len() - 1) as f32;
            let i = x.floor() as usize;
            let j = (i + 1).min(s.len() - 1);
            s[i] + (s[j] - s[i]) * (x - i as f32)
        })
        .collect()
}

impl DetectorModel {
    fn class_model(&self, class_id: i32) -> Option<&ClassModel> {
        self.class.iter().find(|c| c.class_id == class_id)
    }

    /// Recall per height bin of `class_id`: its own where measured, pooled elsewhere.
    fn curve(&self, class_id: i32) -> Vec<f32> {
        match self.class_model(class_id) {
            Some(c) => c
                .recall
                .iter()
                .zip(&c.samples)
                .zip(&self.recall_all)
                .map(|((r, n), all)| if *n >= MIN_SAMPLES { *r } else { *all })
                .collect(),
            None => self.recall_all.clone(),
        }
    }

    /// Probability of detecting an instance of `class_id` whose box is
    /// `height_px` tall in a 640×480 frame with `visible` of it in view.
    pub fn recall(&self, class_id: i32, height_px: f32, visible: f32) -> f32 {
        let curve = self.curve(class_id);
        let h = &self.height_px;
        let by_height = if height_px <= h[0] {
            // Below the smallest bin recall falls to zero with the size.
            curve[0] * (height_px / h[0]).clamp(0.0, 1.0).powi(2)
        } else if height_px >= h[h.len() - 1] {
            curve[curve.len() - 1]
        } else {
            let i = h.partition_point(|&b| b <= height_px) - 1;
            let f = (height_px.ln() - h[i].ln()) / (h[i + 1].ln() - h[i].ln());
            curve[i] + (curve[i + 1] - curve[i]) * f
        };
        (by_height * self.visibility(visible)).clamp(0.0, 1.0)
    }

    /// Recall relative to full visibility at visible fraction `v`.
    pub fn visibility(&self, v: f32) -> f32 {
        let (vs, fs) = (&self.visible_fraction, &self.visibility_factor);
        if v >= 1.0 || !v.is_finite() {
            return *fs.last().expect("validated non-empty");
        }
        if v <= vs[0] {
            // Below the least measured fraction, recall falls in proportion.
            return fs[0] * (v / vs[0]).clamp(0.0, 1.0);
        }
        let i = vs.partition_point(|&b| b <= v).min(vs.len() - 1) - 1;
        let f = (v - vs[i]) / (vs[i + 1] - vs[i]);
        fs[i] + (fs[i + 1] - fs[i]) * f
    }

    /// The class a detection of `class_id` is reported as, for uniform `u`.
    pub fn confuse(&self, class_id: i32, u: f32) -> i32 {
        let mut acc = 0.0;
        match self.class_model(class_id) {
            Some(c) if !c.confusion.is_empty() || c.samples.iter().sum::<u32>() >= MIN_SAMPLES => {
                for x in &c.confusion {
                    acc += x.rate;
                    if u < acc {
                        return x.to;
                    }
                }
                class_id
            }
            _ => match confusable(class_id) {
                Some(to) if u < self.confusion_rate_all => to,
                _ => class_id,
            },
        }
    }

    /// The class of a false positive, for uniform `u`.
    pub fn fp_class_at(&self, u: f32) -> Option<i32> {
        let total: f32 = self.fp_class.iter().map(|c| c.share).sum();
        if total <= 0.0 {
            return None;
        }
        let mut acc = 0.0;
        for c in &self.fp_class {
            acc += c.share / total;
            if u < acc {
                return Some(c.class_id);
            }
        }
        self.fp_class.last().map(|c| c.class_id)
    }
}

/// For a class the photos do not show, the COCO class a detector most
/// plausibly mistakes it for (by shape and context), if any.
pub fn confusable(class_id: i32) -> Option<i32> {
    Some(match class_id {
        1 => 3,   // bicycle → motorcycle
        3 => 1,   // motorcycle → bicycle
        2 => 7,   // car → truck
        7 => 2,   // truck → car
        5 => 7,   // bus → truck
        13 => 56, // bench → chair
        56 => 57, // chair → couch
        57 => 56, // couch → chair
        58 => 75, // potted plant → vase
        75 => 58, // vase → potted plant
        15 => 16, // cat → dog
        16 => 15, // dog → cat
        17 => 16, // horse → dog
        10 => 9,  // fire hydrant → traffic light
        11 => 9,  // stop sign → traffic light
        28 => 24, // suitcase → backpack
        24 => 28, // backpack → suitcase
        60 => 13, // dining table → bench
        62 => 72, // tv → refrigerator
        41 => 39, // cup → bottle
        39 => 41, // bottle → cup
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_profile_parses_and_says_where_it_came_from() {
        let p = Profile::nanodet();
        assert_eq!(p.provenance.tool, "vlnav calibrate-perception");
        assert!(p.provenance.objects > 0 && p.provenance.canvases > 0);
        assert!(!p.provenance.photos.is_empty());
        assert!(p.reid.is_some());
        // Round trip.
        assert_eq!(Profile::parse(&p.to_toml()).unwrap(), p);
    }

    #[test]
    fn recall_grows_with_height_and_visibility() {
        let mut d = Profile::nanodet().detector;
        d.height_px = vec![10.0, 100.0];
        d.recall_all = vec![0.2, 0.8];
        d.visible_fraction = vec![0.5, 1.0];
        d.visibility_factor = vec![0.5, 1.0];
        d.class.clear();
        assert!((d.recall(0, 100.0, 1.0) - 0.8).abs() < 1e-6);
        assert!((d.recall(0, 400.0, 1.0) - 0.8).abs() < 1e-6);
        // Halfway in log-height.
        assert!((d.recall(0, 31.622_776, 1.0) - 0.5).abs() < 1e-4);
        assert!((d.recall(0, 5.0, 1.0) - 0.05).abs() < 1e-6);
        assert!((d.recall(0, 100.0, 0.75) - 0.6).abs() < 1e-6);
        assert!((d.recall(0, 100.0, 0.25) - 0.2).abs() < 1e-6);
    }

    #[test]
    fn deciles_invert() {
        let xs: Vec<f32> = (0..=100).map(|i| i as f32 / 100.0).collect();
        let d = deciles(&xs);
        assert!((d[5] - 0.5).abs() < 1e-6 && d[0] == 0.0 && d[10] == 1.0);
        assert!((from_deciles(&d, 0.25) - 0.25).abs() < 1e-6);
    }

    #[test]
    fn bad_profiles_are_refused_with_the_field() {
        let mut p = Profile::nanodet();
        p.detector.recall_all.pop();
        let e = p.validate().unwrap_err().to_string();
        assert!(e.contains("detector.recall_all"), "{e}");
        let e = Profile::parse("version = 1").unwrap_err().to_string();
        assert!(e.contains("perception profile"), "{e}");
    }

    #[test]
    fn draws_are_uniform_and_keyed() {
        let d = Draws::new(1, hash_str("husky-1"), 5);
        let xs: Vec<f32> = (0..10_000).map(|i| d.uniform(i, 0)).collect();
        let mean = xs.iter().sum::<f32>() / xs.len() as f32;
        assert!((mean - 0.5).abs() < 0.02, "{mean}");
        assert_ne!(d.uniform(3, 0), Draws::new(1, hash_str("husky-2"), 5).uniform(3, 0));
        let n: u32 = (0..10_000).map(|i| d.poisson(i, 0.3)).sum();
        assert!((2700..3300).contains(&n), "{n}");
    }
}
