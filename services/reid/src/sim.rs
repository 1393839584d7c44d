//! The simulation backend's identity reader: the simulator renders a label
//! image (instance id per pixel + a table giving each instance's class and,
//! for named people, identity); the identity under a box is that of the
//! person instance covering most of the box's person pixels.

use std::collections::HashMap;

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
}
