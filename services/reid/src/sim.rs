//! The simulation backend's identity reader: the simulator renders a label
//! image (instance id per pixel + a table giving each instance's class and,
//! for named people, identity); the identity under a box is that of the
//! person instance covering most of the box's person pixels.
//!
//! With a measured [`ReidModel`] (realistic perception) the backend does not
//! hand out the truth: a box's similarity to each enrolled person is drawn
//! from the shipped embedder's measured same-person or different-people
//! similarity distribution, and the usual threshold decides — so a stranger
//! can be taken for the person and the person can be missed, at the rates
//! the real embedder shows.

use std::collections::HashMap;

use vlnav_runtime::perception::{Draws, ReidModel, from_deciles, hash_str};

use crate::preprocess::CropBox;

/// COCO-80 "person".
const PERSON_CLASS: i32 = 0;

/// One row of the label image's instance table.
#[derive(Clone, Debug, PartialEq)]
pub struct LabelledInstance {
    pub class_id: i32,
    pub identity: String,
}

/// A decoded label image.
#[derive(Clone, Debug, PartialEq)]
pub struct Labels {
    pub width: u32,
    pub height: u32,
    /// Instance id per pixel, row-major, 0 = nothing.
    pub ids: Vec<u16>,
    pub instances: HashMap<u32, LabelledInstance>,
}

/// What the labels say about one box.
#[derive(Clone, Debug, PartialEq)]
pub struct LabelledIdentity {
    /// Identity of the dominant person instance (empty for an unnamed person).
    pub identity: String,
    /// Share of the box's person pixels that belong to that instance (0–1).
    pub purity: f32,
}

/// The dominant person instance inside `region` (already clipped to the
/// label image), or `None` when no person pixel lies in it.
pub fn identity_under_box(labels: &Labels, region: CropBox) -> Option<LabelledIdentity> {
    let (x0, y0) = (region.x_min.floor() as u32, region.y_min.floor() as u32);
    let (x1, y1) =
        (region.x_max.ceil().min(labels.width as f32) as u32, region.y_max.ceil().min(labels.height as f32) as u32);
    let mut counts: HashMap<u16, u32> = HashMap::new();
    let mut person_pixels = 0u32;
    for y in y0..y1 {
        let row = &labels.ids[(y * labels.width) as usize..((y + 1) * labels.width) as usize];
        for &id in &row[x0 as usize..x1 as usize] {
            if id == 0 {
                continue;
            }
            if labels.instances.get(&(id as u32)).is_some_and(|i| i.class_id == PERSON_CLASS) {
                *counts.entry(id).or_default() += 1;
                person_pixels += 1;
            }
        }
    }
    // Ties go to the lower id so the answer does not depend on hash order.
    let (&id, &n) = counts.iter().max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(a.0)))?;
    Some(LabelledIdentity {
        identity: labels.instances[&(id as u32)].identity.clone(),
        purity: n as f32 / person_pixels as f32,
    })
}

/// The realistic similarity of a box to enrolled person `candidate`: drawn
/// from the same-person distribution when the box's dominant person *is*
/// the candidate (and covers at least half of its person pixels), from the
/// different-people distribution otherwise. `draws` is keyed by (seed,
/// robot, frame); the box index and the candidate's name pick the draw.
pub fn drawn_similarity(
    model: &ReidModel,
    draws: &Draws,
    box_index: usize,
    truth: Option<&LabelledIdentity>,
    candidate: &str,
) -> f32 {
    let same = truth.is_some_and(|t| t.identity == candidate && t.purity >= 0.5);
    let item = hash_str(candidate) ^ ((box_index as u64) << 40);
    let u = draws.uniform(item, 0);
    from_deciles(if same { &model.same } else { &model.different }, u)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels() -> Labels {
        // 6×2: wall (1) | ana (2) ×3 | bo (3) ×1 | unnamed person (4) ×... row 2.
        let ids = vec![1, 2, 2, 2, 3, 0, 1, 2, 3, 4, 4, 0];
        let mut instances = HashMap::new();
        instances.insert(1, LabelledInstance { class_id: -1, identity: String::new() });
        instances.insert(2, LabelledInstance { class_id: 0, identity: "ana".into() });
        instances.insert(3, LabelledInstance { class_id: 0, identity: "bo".into() });
        instances.insert(4, LabelledInstance { class_id: 0, identity: String::new() });
        Labels { width: 6, height: 2, ids, instances }
    }

    #[test]
    fn the_majority_person_instance_wins_and_walls_do_not_count() {
        let l = labels();
        let whole = CropBox { x_min: 0.0, y_min: 0.0, x_max: 6.0, y_max: 2.0 };
        let got = identity_under_box(&l, whole).unwrap();
        assert_eq!(got.identity, "ana");
        assert!((got.purity - 4.0 / 8.0).abs() < 1e-6, "{got:?}");
        let right = CropBox { x_min: 3.0, y_min: 0.0, x_max: 6.0, y_max: 2.0 };
        let got = identity_under_box(&l, right).unwrap();
        assert_eq!(got.identity, "", "the unnamed person dominates the right half");
        let wall = CropBox { x_min: 0.0, y_min: 0.0, x_max: 1.0, y_max: 2.0 };
        assert_eq!(identity_under_box(&l, wall), None);
    }

    #[test]
    fn drawn_similarities_follow_the_measured_distributions() {
        let model = ReidModel {
            model: "m".into(),
            threshold: 0.8,
            same: (0..=10).map(|k| 0.82 + 0.01 * k as f32).collect(),
            different: (0..=10).map(|k| 0.5 + 0.035 * k as f32).collect(),
            same_pairs: 10,
            different_pairs: 10,
        };
        let ana = LabelledIdentity { identity: "ana".into(), purity: 0.9 };
        let (mut same_hits, mut false_hits) = (0, 0);
        for seq in 0..2000 {
            let d = Draws::new(3, hash_str("husky-1"), seq);
            if drawn_similarity(&model, &d, 0, Some(&ana), "ana") >= 0.8 {
                same_hits += 1;
            }
            if drawn_similarity(&model, &d, 0, Some(&ana), "bo") >= 0.8 {
                false_hits += 1;
            }
        }
        assert_eq!(same_hits, 2000, "every same-person draw is above 0.82");
        // Deciles 0.500, 0.535, …, 0.815, 0.850: 0.8 lies in the ninth tenth
        // (0.780–0.815), so P(different ≥ 0.8) = 0.1 × (0.815 − 0.8) / 0.035
        // + 0.1 (the last tenth) ≈ 14.3 %, about 286 of 2000.
        assert!((240..=330).contains(&false_hits), "{false_hits}");
    }
}
