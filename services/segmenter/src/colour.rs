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

/// A list of classes compiled for labelling pixels: for each of H, S and
/// V, a table of which ranges' bounds hold each value (one bit per range,
/// the ranges numbered class after class), so a pixel's ranges are three
/// lookups ANDed together, and its label is the class of the lowest bit —
/// the first class in the list with a range that holds it, as checking the
/// ranges in turn gives. Checking them in turn took most of the colour
/// segmenter's time at 640 × 480 (docs/reliability.md, "Robots on one
/// gateway").
pub struct Labeller {
    h: Box<[u64; 256]>,
    s: Box<[u64; 256]>,
    v: Box<[u64; 256]>,
    /// The label (what the caller gave with the class) of each range bit.
    label_of_bit: Vec<u8>,
}

impl Labeller {
    /// Up to 64 ranges in all; `None` for more.
    pub fn new(classes: &[(u8, &ColourClass)]) -> Option<Self> {
        let ranges: Vec<(u8, &HsvRange)> =
            classes.iter().flat_map(|(label, c)| c.ranges.iter().map(move |r| (*label, r))).collect();
        if ranges.len() > 64 {
            return None;
        }
        let table = |bounds: fn(&HsvRange) -> [u8; 2]| {
            let mut t = Box::new([0u64; 256]);
            for (bit, (_, r)) in ranges.iter().enumerate() {
                let [lo, hi] = bounds(r);
                for x in lo..=hi {
                    t[x as usize] |= 1 << bit;
                }
            }
            t
        };
        Some(Self {
            h: table(|r| r.h),
            s: table(|r| r.s),
            v: table(|r| r.v),
            label_of_bit: ranges.iter().map(|(label, _)| *label).collect(),
        })
    }

    /// The label of the first class with a range that holds `rgb`, 0 for none.
    #[inline]
    pub fn label(&self, rgb: [u8; 3]) -> u8 {
        let [h, s, v] = rgb_to_hsv(rgb);
        let m = self.h[h as usize] & self.s[s as usize] & self.v[v as usize];
        if m == 0 { 0 } else { self.label_of_bit[m.trailing_zeros() as usize] }
    }
}

/// RGB → HSV exactly as OpenCV's `COLOR_RGB2HSV` on 8-bit images, in
/// integers: H = h° / 2 rounded half up, that is offset + ⌊(60·k + d) / 2d⌋
/// for h° / 2 = offset + 30·k / d (one division, no library call to
/// round; the test checks every colour against the floating-point form).
#[inline]
pub fn rgb_to_hsv([r, g, b]: [u8; 3]) -> [u8; 3] {
    let (r, g, b) = (r as i32, g as i32, b as i32);
    let v = r.max(g).max(b);
    let min = r.min(g).min(b);
    let diff = v - min;
    let s = if v == 0 { 0 } else { (255 * diff + v / 2) / v };
    let h = if diff == 0 {
        0
    } else {
        let (offset, k) = if v == r {
            (if g < b { 180 } else { 0 }, g - b)
        } else if v == g {
            (60, b - r)
        } else {
            (120, r - g)
        };
        // 60·k + d ≥ −59·d > −2d·30, so the floor is the Euclidean quotient.
        offset + (60 * k + diff).div_euclid(2 * diff)
    };
    [h as u8, s as u8, v as u8]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_labeller_gives_the_first_class_with_a_range_that_holds_each_colour() {
        let classes = default_classes();
        // Overlapping classes, in an order that matters: the cable's dark
        // range also holds dark reds.
        let dark_red = ColourClass {
            name: "dark_red".into(),
            ranges: vec![HsvRange { h: [0, 12], s: [60, 255], v: [20, 90] }],
            floor_only: false,
        };
        for list in [vec![&classes[0], &classes[1], &classes[2]], vec![&classes[2], &dark_red, &classes[0]]] {
            let active: Vec<(u8, &ColourClass)> = list.iter().enumerate().map(|(i, c)| (i as u8 + 1, *c)).collect();
            let labeller = Labeller::new(&active).unwrap();
            for r in (0..=255u8).step_by(3) {
                for g in (0..=255u8).step_by(3) {
                    for b in 0..=255u8 {
                        let hsv = rgb_to_hsv([r, g, b]);
                        let in_turn = active
                            .iter()
                            .find(|(_, c)| c.ranges.iter().any(|x| x.contains(hsv)))
                            .map_or(0, |(k, _)| *k);
                        assert_eq!(labeller.label([r, g, b]), in_turn, "rgb {r} {g} {b}");
                    }
                }
            }
        }
        let many = ColourClass { ranges: vec![classes[0].ranges[0]; 65], ..classes[0].clone() };
        assert!(Labeller::new(&[(1, &many)]).is_none(), "more than 64 ranges are checked in turn");
    }

    /// The conversion in floating point, as OpenCV writes it.
    fn in_floats([r, g, b]: [u8; 3]) -> [u8; 3] {
        let (r, g, b) = (r as i32, g as i32, b as i32);
        let v = r.max(g).max(b);
        let diff = v - r.min(g).min(b);
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

    #[test]
    fn the_integer_conversion_equals_the_floating_point_one_on_every_colour() {
        for r in 0..=255u8 {
            for g in 0..=255u8 {
                for b in 0..=255u8 {
                    assert_eq!(rgb_to_hsv([r, g, b]), in_floats([r, g, b]), "rgb {r} {g} {b}");
                }
            }
        }
    }

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
