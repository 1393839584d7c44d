//! The COCO-80 class names, indexed by class id as YOLOv8 numbers them. Class
//! ids in every `vlnav.v1` message (`BoundingBox.class_id`,
//! `ActionStep.class_id`, `LabelInstance.class_id`) index this table.

pub const CLASSES: [&str; 80] = [
    "person",
    "bicycle",
    "car",
    "motorcycle",
    "airplane",
    "bus",
    "train",
    "truck",
    "boat",
    "traffic light",
    "fire hydrant",
    "stop sign",
    "parking meter",
    "bench",
    "bird",
    "cat",
    "dog",
    "horse",
    "sheep",
    "cow",
    "elephant",
    "bear",
    "zebra",
    "giraffe",
    "backpack",
    "umbrella",
    "handbag",
    "tie",
    "suitcase",
    "frisbee",
    "skis",
    "snowboard",
    "sports ball",
    "kite",
    "baseball bat",
    "baseball glove",
    "skateboard",
    "surfboard",
    "tennis racket",
    "bottle",
    "wine glass",
    "cup",
    "fork",
    "knife",
    "spoon",
    "bowl",
    "banana",
    "apple",
    "sandwich",
    "orange",
    "broccoli",
    "carrot",
    "hot dog",
    "pizza",
    "donut",
    "cake",
    "chair",
    "couch",
    "potted plant",
    "bed",
    "dining table",
    "toilet",
    "tv",
    "laptop",
    "mouse",
    "remote",
    "keyboard",
    "cell phone",
    "microwave",
    "oven",
    "toaster",
    "sink",
    "refrigerator",
    "book",
    "clock",
    "vase",
    "scissors",
    "teddy bear",
    "hair drier",
    "toothbrush",
];

/// The class name of `id`, if it is a COCO-80 class.
pub fn name(id: i32) -> Option<&'static str> {
    usize::try_from(id).ok().and_then(|i| CLASSES.get(i)).copied()
}

/// The class id of an exact COCO-80 name.
pub fn id(name: &str) -> Option<i32> {
    CLASSES.iter().position(|c| *c == name).map(|i| i as i32)
}

#[cfg(test)]
mod tests {
    #[test]
    fn ids_match_the_yolov8_numbering_the_paper_uses() {
        assert_eq!(super::id("person"), Some(0));
        assert_eq!(super::id("bicycle"), Some(1));
        assert_eq!(super::id("elephant"), Some(20));
        assert_eq!(super::id("bottle"), Some(39));
        assert_eq!(super::id("chair"), Some(56));
        assert_eq!(super::id("potted plant"), Some(58));
        assert_eq!(super::name(79), Some("toothbrush"));
        assert_eq!(super::name(80), None);
        assert_eq!(super::name(-1), None);
    }
}
