//! The dynamic front-end on real people: the first 10 frames of TUM fr3/walking_halfsphere (RGB
//! only, so the paper's culling without our depth rules), YOLOX-nano boxes, a hand-held camera.
//! In these frames the man on the right stands up and turns; the man on the left types.
//! Keypoints outside every person box are the static office: few of them may be culled.
//! Measured (frames 1-9): 0.779 of the person-box keypoints culled, 0.047 of the rest; without
//! the unknown-objects rule (not depth-gated without depth) 0.024 of the rest: the rule culls
//! ~50 office keypoints in frames 4-5 around the robot arm and shelf on the right, where the
//! hand-held camera's epipolar outliers cluster; the other culls are in boxes judged moving
//! (the monitor behind the man who stands up).
//!
//! Run with `cargo test --release --features tract --test end_to_end dynamic_real_tum:: -- --ignored --nocapture`.

use crate::common::shared;
use std::sync::{Arc, Mutex};
use stillpoint_detect::{
    DetectError, DetectInput, DetectSettings, Detection, Detector, YoloxDetector,
};
use stillpoint_features::{OrbExtractor, OrbParams};
use stillpoint_frontend::{DynamicFrontEnd, FrontEndSettings};
use stillpoint_frontend::{FrameInput, FrontEnd};

/// YOLOX that also hands its boxes to the test.
struct Recording {
    inner: YoloxDetector,
    seen: Arc<Mutex<Vec<Detection>>>,
}

impl Detector for Recording {
    fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
        let d = self.inner.detect(input)?;
        *self.seen.lock().unwrap() = d.clone();
        Ok(d)
    }
    fn name(&self) -> &str {
        "recording"
    }
}

#[test]
#[ignore = "needs ../shared/data"]
fn real_walkers_are_culled_and_the_office_is_kept() {
    let dir = shared().join("data/tum/fr3_walking_halfsphere_first10_rgb");
    let list = stillpoint_datasets::read_stamped_list(&dir.join("rgb.txt"), &dir).unwrap();
    let model = shared().join("models/yolox_nano_480x640.onnx");
    let seen = Arc::new(Mutex::new(Vec::new()));
    let detector = Recording {
        inner: YoloxDetector::load(&model, &DetectSettings::default()).unwrap(),
        seen: seen.clone(),
    };
    let mut front = DynamicFrontEnd::new(Box::new(detector), FrontEndSettings::default());
    let mut orb = OrbExtractor::new(OrbParams::default());
    let (mut people, mut people_culled, mut office, mut office_culled) = (0, 0, 0, 0);
    for (i, (t, file)) in list.iter().enumerate() {
        let rgb = stillpoint_image::read_rgb(file).unwrap();
        let gray = stillpoint_image::rgb_to_gray(&rgb);
        let kps: Vec<[f32; 2]> = orb
            .extract(&gray)
            .keypoints
            .iter()
            .map(|k| [k.x, k.y])
            .collect();
        let out = front.judge(
            &FrameInput {
                index: i,
                timestamp: *t,
                gray: &gray,
                rgb: Some(&rgb),
                depth: None,
                previous: None,
                own_boxes: false,
            },
            &kps,
        );
        let dets = seen.lock().unwrap().clone();
        let in_person = |[x, y]: [f32; 2]| {
            dets.iter()
                .any(|d| d.class_id == 0 && d.bbox.contains_strict(x, y))
        };
        let (mut p, mut pc, mut o, mut oc) = (0, 0, 0, 0);
        for (&k, &d) in kps.iter().zip(&out.dynamic) {
            if in_person(k) {
                p += 1;
                pc += usize::from(d);
            } else {
                o += 1;
                oc += usize::from(d);
            }
        }
        eprintln!(
            "frame {i}: {} people; in person boxes {pc} of {p} culled, elsewhere {oc} of {o}",
            dets.iter().filter(|d| d.class_id == 0).count()
        );
        if i > 0 {
            (people, people_culled, office, office_culled) = (
                people + p,
                people_culled + pc,
                office + o,
                office_culled + oc,
            );
        }
    }
    let (in_people, in_office) = (
        people_culled as f64 / people.max(1) as f64,
        office_culled as f64 / office.max(1) as f64,
    );
    eprintln!("culled: {in_people:.3} of person-box keypoints, {in_office:.3} of the rest");
    assert!(people > 0, "YOLOX found no person");
    assert!(in_people > 0.3, "{in_people}");
    assert!(in_office < 0.08, "{in_office}");
}
