//! The 80 COCO class names in the order YOLOX (and every COCO-trained detector) numbers them.

/// COCO class names, index = class id (`../shared/models/coco_classes.txt`).
pub const COCO_CLASSES: [&str; 80] = [
    "person",
    "bicycle",
    "car",
    "motorbike",
    "aeroplane",
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
    "sofa",
    "pottedplant",
    "bed",
    "diningtable",
    "toilet",
    "tvmonitor",
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

/// Name of a class id, `"unknown"` beyond the table.
pub fn class_name(class_id: u16) -> &'static str {
    COCO_CLASSES
        .get(class_id as usize)
        .copied()
        .unwrap_or("unknown")
}

/// Class id of a COCO name (exact, lower case as in the table).
///
/// ```
/// assert_eq!(stillpoint_detection::classes::class_id("tvmonitor"), Some(62));
/// ```
pub fn class_id(name: &str) -> Option<u16> {
    COCO_CLASSES
        .iter()
        .position(|&n| n == name)
        .map(|i| i as u16)
}
