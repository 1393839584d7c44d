//! Whether a box is the size its class can be at the depth measured in it:
//! a false positive on a wall a metre away (a poster, a pattern) puts a
//! "person" there half a metre tall, and a few of them in a row pass the
//! consistency check of the class vote. Used with `--size-check true`
//! (off by default; docs/perception.md, the FIND's rules, and
//! docs/evaluation.md, "Generated worlds", for what it measured).

use nalgebra::Vector3;

use super::find::pixel_from;

use crate::executor::model::{Detection, Frame};

/// Heights of whole objects (m, smallest and largest in everyday use) of
/// the COCO classes a FIND is given: a child to a tall adult; a stop sign's
/// plate alone to the sign on its post; a tv's screen to one on its stand.
/// A class not listed is not checked.
const HEIGHTS: &[(i32, f64, f64)] = &[
    (0, 1.0, 2.0),   // person
    (1, 0.6, 1.3),   // bicycle
    (2, 1.2, 2.0),   // car
    (3, 0.8, 1.5),   // motorcycle
    (5, 2.5, 4.2),   // bus
    (7, 1.8, 4.2),   // truck
    (10, 0.4, 1.1),  // fire hydrant
    (11, 0.45, 2.5), // stop sign
    (13, 0.4, 1.1),  // bench
    (24, 0.3, 0.7),  // backpack
    (26, 0.2, 0.5),  // handbag
    (28, 0.4, 0.9),  // suitcase
    (39, 0.1, 0.4),  // bottle
    (56, 0.7, 1.2),  // chair
    (57, 0.6, 1.1),  // couch
    (58, 0.2, 2.0),  // potted plant
    (59, 0.4, 1.4),  // bed
    (60, 0.6, 0.9),  // dining table
    (62, 0.3, 1.5),  // tv
    (63, 0.2, 0.4),  // laptop
    (72, 1.2, 2.0),  // refrigerator
];

/// The share of its smallest height a box may show: half the object hidden
/// (a person behind a desk). The detector finds objects less than half in
/// view in few frames (docs/perception.md, visibility).
const MIN_SHOWN: f64 = 0.5;
/// How much taller than its largest height a box may make an object: the
/// box edges' jitter (σ 5 % of the box) and the depth's error at range.
const MAX_SLACK: f64 = 1.5;
/// A box edge this near the image's top or bottom row is cut off there, px.
const EDGE_PX: f32 = 1.0;

/// `b`'s height in the image, at the depth `target` (`odom`; the box's own
/// estimate) is seen at from this frame, is a height its class can have. True when it cannot be
/// told: no camera model, the target not in front, a class not listed; a
/// box cut off by the image's top or bottom edge may be short but not tall.
pub(super) fn fits_class(frame: &Frame, b: &Detection, target: &Vector3<f64>) -> bool {
    let Some(&(_, smallest, largest)) = HEIGHTS.iter().find(|(c, _, _)| *c == b.class_id) else { return true };
    let Some(camera) = frame.camera.as_ref() else { return true };
    let Some((_, _, depth)) = pixel_from(camera, &frame.pose, target) else { return true };
    let height = f64::from(b.y_max - b.y_min) * depth / camera.intrinsics.fy;
    let cut = b.y_min <= EDGE_PX || b.y_max >= camera.height as f32 - EDGE_PX;
    height <= MAX_SLACK * largest && (cut || height >= MIN_SHOWN * smallest)
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;

    /// A box `h` px tall in the middle of the 160 × 120 test image.
    fn tall(class_id: i32, h: f32) -> Detection {
        Detection { y_min: 60.0 - h / 2.0, y_max: 60.0 + h / 2.0, class_id, ..person(70.0, 90.0) }
    }

    #[test]
    fn a_person_on_a_wall_a_metre_away_is_too_small_and_one_far_off_too_tall() {
        // fy 80, camera 0.3 m ahead of base_link: a target 1.3 m ahead is 1 m deep.
        let frame = at(0.0, 0.0, 0.0, 0.0);
        let near = Vector3::new(1.3, 0.0, 0.5);
        assert!(!fits_class(&frame, &tall(0, 30.0), &near), "0.38 m tall: a false positive");
        assert!(fits_class(&frame, &tall(0, 60.0), &near), "0.75 m: a person half hidden");
        let far = Vector3::new(8.3, 0.0, 0.5);
        assert!(fits_class(&frame, &tall(0, 20.0), &far), "2 m");
        assert!(!fits_class(&frame, &tall(0, 40.0), &far), "4 m: no person");
    }

    #[test]
    fn a_box_cut_off_by_the_image_edge_may_be_short_and_an_unlisted_class_is_not_checked() {
        let frame = at(0.0, 0.0, 0.0, 0.0);
        let near = Vector3::new(1.3, 0.0, 0.5);
        let cut = Detection { y_min: 100.0, y_max: 120.0, ..tall(0, 20.0) };
        assert!(fits_class(&frame, &cut, &near), "the rest of the person is below the image");
        assert!(fits_class(&frame, &tall(90, 5.0), &near), "class 90 has no listed height");
    }

    #[test]
    fn the_depth_is_the_targets_from_where_the_robot_stands_now() {
        // The same target, seen from 4 m nearer: the same box is 4 m less deep.
        let target = Vector3::new(5.3, 0.0, 0.5);
        assert!(fits_class(&at(0.0, 0.0, 0.0, 0.0), &tall(56, 20.0), &target), "1.25 m at 5 m");
        assert!(!fits_class(&at(0.0, 4.0, 0.0, 0.0), &tall(56, 20.0), &target), "0.25 m at 1 m: no chair");
    }
}
