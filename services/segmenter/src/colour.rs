//! Colour classes: HSV thresholds on OpenCV's 8-bit scale (H 0–180, S and V
//! 0–255), as the authors threshold their red-marked no-go zones.

use serde::{Deserialize, Serialize};

/// One HSV box; a pixel inside every bound (inclusive) matches.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HsvRange {
    pub h: [u8; 2],
    pub s: [u8; 2],
    pub v: [u8; 2],
}

impl HsvRange {
    pub fn contains(&self, [h, s, v]: [u8; 3]) -> bool {
        (self.h[0]..=self.h[1]).contains(&h)
            && (self.s[0]..=self.s[1]).contains(&s)
            && (self.v[0]..=self.v[1]).contains(&v)
    }
}

/// A semantic class recognised by colour.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ColourClass {
    pub name: String,
    /// The class matches when any range does (red wraps around H = 0).
    pub ranges: Vec<HsvRange>,
    /// Keep only pixels whose 3-D point lies on the floor (markings, tape, cables).
    #[serde(default = "yes")]
    pub floor_only: bool,
}

fn yes() -> bool {
    true
}

/// The default class table:
/// - `restricted_zone`: the authors' red, H 0–10 or 170–180, S ≥ 120, V ≥ 70;
/// - `hazard`: the yellow of yellow-black hazard tape, H 20–34, S ≥ 120, V ≥ 120
///   (the black stripes are left to the yellow ones either side);
/// - `cable`: a dark (black or dark grey) cable on a lighter floor, V ≤ 45 with
///   S ≤ 90 — dark floors or deep shadows also match, so adjust it to the site.
pub fn default_classes() -> Vec<ColourClass> {
    vec![
        ColourClass {
            name: "restricted_zone".into(),
            ranges: vec![
                HsvRange { h: [0, 10], s: [120, 255], v: [70, 255] },
                HsvRange { h: [170, 180], s: [120, 255], v: [70, 255] },
            ],
            floor_only: true,
        },
        ColourClass {
            name: "hazard".into(),
            ranges: vec![HsvRange { h: [20, 34], s: [120, 255], v: [120, 255] }],
            floor_only: true,
        },
        ColourClass {
            name: "cable".into(),
            ranges: vec![HsvRange { h: [0, 180], s: [0, 90], v: [0, 45] }],
            floor_only: true,
        },
    ]
}

/// RGB → HSV exactly as OpenCV's `COLOR_RGB2HSV` on 8-bit images.
pub fn rgb_to_hsv([r, g, b]: [u8; 3]) -> [u8; 3] {
    let (r, g, b) = (r as i32, g as i32, b as i32);
    let v = r.max(g).max(b);
    let min = r.min(g).min(b);
    let diff = v - min;
    let s = if v == 0 { 0 } else { (255 * diff + v / 2) / v };
    let h = if diff == 0 {
        0.0
    } else {
        let d = diff as f32;
        let h = if v == r {
            60.0 * (g - b) as f32 / d
        } else if v == g {
            120.0 + 60.0 * (b - r) as f32 / d
        } else {
            240.0 + 60.0 * (r - g) as f32 / d
        };
        if h < 0.0 { h + 360.0 } else { h }
    };
    [(h / 2.0).round() as u8, s as u8, v as u8]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hsv_matches_opencv_on_reference_colours() {
        // Values from cv2.cvtColor(np.uint8([[c]]), cv2.COLOR_RGB2HSV).
        assert_eq!(rgb_to_hsv([255, 0, 0]), [0, 255, 255]);
        assert_eq!(rgb_to_hsv([0, 255, 0]), [60, 255, 255]);
        assert_eq!(rgb_to_hsv([0, 0, 255]), [120, 255, 255]);
        assert_eq!(rgb_to_hsv([255, 255, 0]), [30, 255, 255]);
        assert_eq!(rgb_to_hsv([128, 128, 128]), [0, 0, 128]);
        assert_eq!(rgb_to_hsv([200, 30, 60]), [175, 217, 200]);
    }

    #[test]
    fn default_red_accepts_both_ends_of_the_hue_circle() {
        let red = &default_classes()[0];
        let hit = |rgb| red.ranges.iter().any(|r| r.contains(rgb_to_hsv(rgb)));
        assert!(hit([220, 20, 20]));
        assert!(hit([200, 30, 60]), "crimson wraps to H≈175");
        assert!(!hit([220, 120, 120]), "pink is not saturated enough");
        assert!(!hit([60, 10, 10]), "too dark");
        assert!(!hit([220, 140, 20]), "orange");
    }
}
