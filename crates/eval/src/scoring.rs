//! A run scored against its sequence's truth, beside the run and not in it: [`run_scored`]
//! runs [`stillpoint_run::run_with`] with `TruthScoring` as one more sink (the generator's
//! masks per frame and the map at the end; the ground truth read and the accuracy) and the
//! masks as the dense cloud's truth.

use std::cell::RefCell;
use std::path::PathBuf;

use stillpoint_image::Gray8;
use stillpoint_run::{Ended, Event, MovingPixels, RunError, RunOptions, RunSummary, Sink, Tracked};
use stillpoint_trajectory::{Alignment, AteOptions, AteResult, RpeResult, Trajectory};

use crate::movers::{self, MoversInMap};

/// A run and what its sequence's truth says of it.
pub struct ScoredRun {
    /// The run.
    pub run: RunSummary,
    /// The sequence's ground truth, when it has one that could be read.
    pub ground_truth: Option<Trajectory>,
    /// With the generator's per-pixel masks (`mask/` of a `stillpoint synth --masks` sequence):
    /// keypoints handed to tracking that lie on moving objects, per frame.
    pub moving_kept_per_frame: Option<Vec<usize>>,
    /// ... and the share of the keypoints off the moving objects that were culled, per frame
    /// (static world the front-end took for movers).
    pub static_culled_share_per_frame: Option<Vec<f64>>,
    /// ... and map points at the end with at least one keyframe observation on a moving object.
    pub moving_map_points: Option<MoversInMap>,
}

impl ScoredRun {
    /// How the trajectory is aligned to the ground truth (Sim(3) for monocular, else SE(3)).
    pub fn alignment(&self) -> Alignment {
        crate::alignment(self.run.sensor)
    }

    /// ATE and translational RPE over 1 s against the ground truth, when there is one
    /// ([`crate::accuracy()`]).
    pub fn accuracy(&self) -> Option<(AteResult, Option<RpeResult>)> {
        let gt = self.ground_truth.as_ref()?;
        crate::accuracy(gt, &self.run.trajectory, self.run.sensor)
    }

    /// ATE of the keyframe trajectory against the ground truth (SE(3)-aligned), when there is
    /// one and a keyframe associates.
    pub fn keyframe_ate(&self) -> Option<AteResult> {
        let gt = self.ground_truth.as_ref()?;
        let options = AteOptions {
            align: Alignment::Se3,
            ..Default::default()
        };
        stillpoint_trajectory::ate(gt, &self.run.keyframe_trajectory, &options).ok()
    }

    /// mean / median / p90 of the keypoints kept on moving objects per frame, when the sequence
    /// has masks.
    pub fn moving_kept_stats(&self) -> Option<(f64, f64, f64)> {
        let v: Vec<f64> = self
            .moving_kept_per_frame
            .as_ref()?
            .iter()
            .map(|&c| c as f64)
            .collect();
        Some(crate::stats(&v))
    }

    /// mean / median / p90 of the share of static keypoints culled per frame, when the
    /// sequence has masks.
    pub fn static_culled_stats(&self) -> Option<(f64, f64, f64)> {
        Some(crate::stats(self.static_culled_share_per_frame.as_ref()?))
    }
}

/// A run of `o` ([`stillpoint_run::run_sequence`]) scored against its sequence's truth.
pub fn run_scored(o: &RunOptions, progress: &mut dyn FnMut(Event)) -> Result<ScoredRun, RunError> {
    let masks = MaskFolder {
        dataset: o.dataset.clone(),
        last: RefCell::new(None),
    };
    let has_masks = o.dataset.join("mask").is_dir();
    let mut scoring = TruthScoring::new(has_masks.then_some(&masks));
    let truth = has_masks.then_some(&masks as &dyn MovingPixels);
    let run = stillpoint_run::run_with(o, truth, &mut [&mut scoring], progress)?;
    Ok(ScoredRun {
        run,
        ground_truth: scoring.ground_truth,
        moving_kept_per_frame: has_masks.then_some(scoring.moving_kept),
        static_culled_share_per_frame: has_masks.then_some(scoring.static_culled),
        moving_map_points: scoring.moving_map_points,
    })
}

/// The generator's masks of a synthetic sequence (`mask/`), by timestamp. The last one read is
/// kept: on a keyframe the dense cloud and the scoring ask for the same frame's.
struct MaskFolder {
    dataset: PathBuf,
    last: RefCell<Option<(u64, Option<Gray8>)>>,
}

impl MovingPixels for MaskFolder {
    fn moving_mask(&self, timestamp: f64) -> Option<Gray8> {
        let key = timestamp.to_bits();
        if let Some((t, mask)) = self.last.borrow().as_ref()
            && *t == key
        {
            return mask.clone();
        }
        let mask = movers::moving_mask(&self.dataset, timestamp);
        *self.last.borrow_mut() = Some((key, mask.clone()));
        mask
    }
}

/// The sink that scores: keypoints on movers per frame (with masks), map points on movers and
/// the ground truth at the end.
struct TruthScoring<'a> {
    masks: Option<&'a MaskFolder>,
    moving_kept: Vec<usize>,
    static_culled: Vec<f64>,
    moving_map_points: Option<MoversInMap>,
    ground_truth: Option<Trajectory>,
}

impl<'a> TruthScoring<'a> {
    fn new(masks: Option<&'a MaskFolder>) -> Self {
        Self {
            masks,
            moving_kept: Vec::new(),
            static_culled: Vec::new(),
            moving_map_points: None,
            ground_truth: None,
        }
    }
}

impl Sink for TruthScoring<'_> {
    fn frame(&mut self, t: &Tracked) -> Result<(), RunError> {
        let Some(masks) = &self.masks else {
            return Ok(());
        };
        let r = t.result;
        let mask = masks.moving_mask(t.frame.timestamp);
        let kept = mask
            .as_ref()
            .map(|m| movers::moving_keypoints_kept(m, &r.keypoints, &r.dynamic));
        self.moving_kept.push(kept.unwrap_or(0));
        if let Some(share) = mask
            .as_ref()
            .and_then(|m| movers::static_keypoints_culled_share(m, &r.keypoints, &r.dynamic))
        {
            self.static_culled.push(share);
        }
        tracing::debug!(
            frame = r.index,
            // Kept keypoints and pose inliers on the generator's movers.
            kept_on_movers = kept,
            inliers_on_movers = mask.as_ref().map(|m| movers::moving_keypoints_matched(
                m,
                &r.keypoints,
                &r.matched
            )),
            "scored"
        );
        Ok(())
    }

    fn finish(&mut self, e: &Ended) -> Result<(), RunError> {
        self.ground_truth = e.sequence.ground_truth().and_then(|p| {
            crate::read_ground_truth(e.sequence, &p)
                .map_err(|e| {
                    tracing::warn!(
                        "ground truth unreadable: {}",
                        stillpoint_run::error_chain(&e)
                    )
                })
                .ok()
        });
        // A loaded map's keyframes carry another sequence's timestamps: no masks to judge them.
        if let (Some(masks), false) = (&self.masks, e.map_loaded) {
            let map = e.finished.system.map();
            self.moving_map_points = Some(map.lock().map_or(Default::default(), |map| {
                movers::moving_map_points(&map, |t| masks.moving_mask(t))
            }));
        }
        Ok(())
    }
}
