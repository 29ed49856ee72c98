//! The detector on its own thread, and the boxes it finished carried to the current frame.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use stillpoint_detect::{DetectError, Detection, Detector, DetectorThread, JobQueue};
use stillpoint_image::{Gray8, Rgb8};

use crate::{FrameInput, FrontEndSettings};

/// The detector on its own thread ([`DynamicFrontEnd::detect_in_background`]): each frame hands
/// it the frame when it is idle and takes the newest boxes it has finished, carried from their
/// frame to the current one by the median flow of the corners tracked inside each box, frame by
/// frame; tracking never waits for it (but on the first frame, so that the first map is judged).
pub(crate) struct BackgroundDetector {
    thread: DetectorThread,
    /// A frame is with the detector.
    busy: bool,
    /// The timestamp of the last frame handed to the detector.
    last_sent: Option<f64>,
    /// [`FrontEndSettings::background_detect_interval_s`].
    interval_s: f64,
    /// [`FrontEndSettings::background_detect_max_wait_s`].
    max_wait_s: f64,
    /// [`FrontEndSettings::background_detect_max_wait_without_mover_s`].
    max_wait_without_mover_s: f64,
    /// [`FrontEndSettings::background_detect_wait_slice_s`].
    wait_slice: std::time::Duration,
    /// Classes that move on their own (people, animals, vehicles): while one is in view a late
    /// detection is waited for whole; with none, in slices (someone may have walked in, but a
    /// whole wait stops a fast turn for an inference).
    movable_classes: Vec<u16>,
    /// [`FrontEndSettings::background_detect_at_side_edge`].
    at_side_edge_every_frame: bool,
    /// A schedule of frames instead of time: (every, lag) frames
    /// ([`FrontEndSettings::background_detect_every_frames`]).
    schedule: Option<(usize, usize)>,
    /// On a schedule: the frame with the detector, whose boxes are still to be taken.
    pending: Option<usize>,
    /// On a schedule: the frame with the detector because it needs its own boxes
    /// ([`BackgroundDetector::detect_own`]); it waits for them.
    own: Option<usize>,
    /// The newest finished boxes, already carried to frame `at`, and the frame they were
    /// detected on.
    latest: Option<CarriedDetections>,
    /// Corner tracks into each recent frame (frame index, tracks), to carry boxes detected on
    /// an earlier frame.
    tracks: std::collections::VecDeque<(usize, Vec<stillpoint_dynamic::TrackedPoint>)>,
    /// [`FrontEndSettings::background_detect_ahead`].
    ahead: bool,
    /// On a schedule: frames already queued with the thread, by [`DetectionPrefetch`] (a
    /// recording's reader, frames ahead) or by this; shared with the prefetch.
    queued: Arc<Mutex<BTreeSet<usize>>>,
    /// Frames ask for their own boxes (a monocular map starting): the prefetch holds back,
    /// since each of those frames would wait behind the scheduled frames queued ahead.
    asking_own: Arc<AtomicBool>,
    /// On a schedule: the frame whose boxes the next wait takes.
    in_flight: Option<usize>,
    /// On a schedule: boxes the thread returned before their frame's turn, by frame.
    early: BTreeMap<usize, Result<Vec<Detection>, DetectError>>,
}

/// The scheduled frames of a recording handed to the detector's thread as soon as they are
/// decoded, ahead of tracking ([`crate::FrontEnd::detection_prefetch`]): the detector
/// then works while the frames before are tracked and mapped, and each frame's boxes are
/// waiting when its turn comes. A frame's boxes depend on nothing but the frame, and they are
/// taken at the same frame as without it, so the run is the same, only sooner.
#[derive(Clone, Debug)]
pub struct DetectionPrefetch {
    queue: JobQueue,
    queued: Arc<Mutex<BTreeSet<usize>>>,
    asking_own: Arc<AtomicBool>,
    every: usize,
}

impl DetectionPrefetch {
    /// Queue frame `index` with the detector when it is on the schedule and not queued yet:
    /// the same image the front-end would hand it (`rgb`, else `gray` as colour).
    pub fn offer(&self, index: usize, timestamp: f64, gray: &Gray8, rgb: Option<&Rgb8>) {
        if !index.is_multiple_of(self.every) || self.asking_own.load(Ordering::Relaxed) {
            return;
        }
        let mut queued = self.queued.lock().unwrap_or_else(PoisonError::into_inner);
        if queued.contains(&index) {
            return;
        }
        let rgb = detector_image(gray, rgb);
        // A stopped detector: the front-end hears of it when it hands over a frame.
        if self.queue.send(index, timestamp, Arc::new(rgb)).is_ok() {
            queued.insert(index);
        }
    }
}

/// What the detector looks at: the colour image, else the gray one as colour. One place for
/// the front-end and the prefetch, which must hand it the same image.
fn detector_image(gray: &Gray8, rgb: Option<&Rgb8>) -> Rgb8 {
    match rgb {
        Some(rgb) => rgb.clone(),
        None => stillpoint_image::gray_to_rgb(gray),
    }
}

/// Boxes detected on frame `detected`, moved to frame `at`.
struct CarriedDetections {
    detected: usize,
    at: usize,
    boxes: Vec<Detection>,
}

/// Whether a box reaches the left or right edge of an image `width` pixels wide (within
/// [`stillpoint_dynamic::AT_BORDER_PX`], as boxes carried in view keep such edges): someone
/// coming into view, or leaving it.
fn at_side_edge(boxes: &[Detection], width: f32) -> bool {
    use stillpoint_dynamic::AT_BORDER_PX;
    boxes
        .iter()
        .any(|d| d.bbox.x1 <= AT_BORDER_PX || d.bbox.x2 >= width - AT_BORDER_PX)
}

/// Frames after which boxes carried from an older detection are dropped.
const MAX_DETECTION_AGE: usize = 15;

impl BackgroundDetector {
    /// `detector` on a thread of its own, `settings.background_detect_nice` steps below the
    /// caller's priority (`background_detect_nice_on_schedule` on a schedule of frames).
    pub(crate) fn spawn(
        detector: Box<dyn Detector>,
        settings: &FrontEndSettings,
    ) -> Result<Self, DetectError> {
        let nice = if settings.background_detect_every_frames > 0 {
            settings.background_detect_nice_on_schedule
        } else {
            settings.background_detect_nice
        };
        let thread = DetectorThread::spawn(move || {
            stillpoint_core::lower_this_thread_priority(nice);
            Ok(detector)
        })?;
        Ok(Self {
            thread,
            busy: false,
            last_sent: None,
            interval_s: settings.background_detect_interval_s,
            max_wait_s: settings.background_detect_max_wait_s,
            max_wait_without_mover_s: settings.background_detect_max_wait_without_mover_s,
            // a setting of inf waits whole, like NaN or below 0 not at all (never a panic)
            wait_slice: std::time::Duration::try_from_secs_f64(
                settings.background_detect_wait_slice_s.max(0.0),
            )
            .unwrap_or(std::time::Duration::MAX),
            movable_classes: settings.dynamic.objects.movable_classes.clone(),
            at_side_edge_every_frame: settings.background_detect_at_side_edge,
            schedule: (settings.background_detect_every_frames > 0).then(|| {
                let every = settings.background_detect_every_frames;
                (every, settings.background_detect_lag_frames.clamp(1, every))
            }),
            pending: None,
            own: None,
            latest: None,
            tracks: std::collections::VecDeque::new(),
            ahead: settings.background_detect_ahead,
            queued: Arc::default(),
            asking_own: Arc::default(),
            in_flight: None,
            early: BTreeMap::new(),
        })
    }

    /// On a schedule of frames (and `background_detect_ahead`), a handle that queues scheduled
    /// frames ahead of tracking.
    pub(crate) fn prefetch(&self) -> Option<DetectionPrefetch> {
        let (every, _) = self.schedule.filter(|_| self.ahead)?;
        Some(DetectionPrefetch {
            queue: self.thread.queue(),
            queued: Arc::clone(&self.queued),
            asking_own: Arc::clone(&self.asking_own),
            every,
        })
    }

    /// On a schedule, at frame `index` (once a frame, from `boxes_for`): forget what was queued
    /// or returned for frames before it (none of them is handed over again), but the frame
    /// whose boxes are awaited.
    fn forget_before(&mut self, index: usize) {
        if self.schedule.is_none() {
            return;
        }
        let keep = self.in_flight;
        self.early.retain(|&i, _| i >= index || Some(i) == keep);
        self.queued
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .retain(|&i| i >= index || Some(i) == keep);
    }

    /// On a schedule of frames: hand the thread `frame` now, after taking the detection it
    /// holds, so that [`BackgroundDetector::boxes_for`] gives the frame its own boxes (a
    /// monocular map starting, `FrameInput::own_boxes`). Called before the motion check, which
    /// then runs beside the detector as inline.
    pub(crate) fn detect_own(&mut self, frame: &FrameInput) {
        if self.schedule.is_none() {
            return;
        }
        if self.busy {
            self.pending = None;
            self.wait_for_detection(frame.index);
        }
        self.send(frame);
        if self.busy {
            self.own = Some(frame.index);
        }
    }

    /// On a schedule of frames: hand the thread `frame` now, before the motion check, when it
    /// is due and the thread idle, so that the detector has the frame's motion check and ORB
    /// to work beside as well. The boxes are the same ([`BackgroundDetector::boxes_for`] would
    /// hand it this frame after the check, the thread as idle: nothing takes or sends between),
    /// only sooner, and the frame that takes them waits less.
    pub(crate) fn send_if_due(&mut self, frame: &FrameInput) {
        self.asking_own.store(frame.own_boxes, Ordering::Relaxed);
        if self.schedule.is_some() && !self.busy && self.due(frame) {
            self.send(frame);
            if self.busy {
                self.pending = Some(frame.index);
            }
        }
    }

    /// Whether `frame` is one the detector should take: on the schedule, or (live) the
    /// interval since the last frame sent has passed.
    fn due(&self, frame: &FrameInput) -> bool {
        match self.schedule {
            Some((every, _)) => frame.index.is_multiple_of(every),
            None => self
                .last_sent
                .is_none_or(|t| frame.timestamp - t >= self.interval_s),
        }
    }

    /// Boxes for frame `index` (whose corner tracks are `tracks`): collect what the thread has
    /// finished, carry the newest to this frame, and hand the thread this frame when it is idle.
    pub(crate) fn boxes_for(
        &mut self,
        frame: &FrameInput,
        tracks: &[stillpoint_dynamic::TrackedPoint],
    ) -> Vec<Detection> {
        self.forget_before(frame.index);
        self.tracks.push_back((frame.index, tracks.to_vec()));
        while self.tracks.len() > MAX_DETECTION_AGE + 1 {
            self.tracks.pop_front();
        }
        if self.own.take().is_some_and(|own| own == frame.index) {
            self.wait_for_detection(frame.index);
            return self.boxes_detected_on(frame.index);
        }
        match (self.schedule, self.pending) {
            // On a schedule the boxes are taken at a fixed frame, never as they happen to come.
            (Some((_, lag)), Some(sent)) if frame.index >= sent + lag => {
                self.pending = None;
                self.wait_for_detection(sent);
            }
            (Some(_), _) => {}
            (None, _) => {
                while let Some(done) = self.thread.try_recv() {
                    self.take(done);
                }
                // live, the detector behind: with a mover in the newest boxes wait for the
                // frame it holds rather than go on with boxes too old (frames arriving
                // meanwhile are dropped); without one, someone may have come into view since:
                // give the detector a slice of the core on each frame until it finishes
                let held_for = self.last_sent.map(|t| frame.timestamp - t);
                let overdue = |limit: f64| limit > 0.0 && held_for.is_some_and(|h| h > limit);
                if self.busy && self.mover_in_view() {
                    if overdue(self.max_wait_s) {
                        self.wait_for_detection(frame.index);
                    }
                } else if self.busy && overdue(self.max_wait_without_mover_s) {
                    self.wait_for_detection_at_most(frame.index, Some(self.wait_slice));
                }
            }
        }
        if let Some(l) = self.latest.as_mut() {
            let from = l.at;
            let (w, h) = (frame.gray.width as f32, frame.gray.height as f32);
            for (index, pts) in self.tracks.iter().filter(|(i, _)| *i > from) {
                for d in &mut l.boxes {
                    d.bbox = stillpoint_dynamic::moved_by_flow_in_view(&d.bbox, pts, w, h);
                }
                l.at = *index;
            }
        }
        let entering = self
            .latest
            .as_ref()
            .is_some_and(|l| at_side_edge(&l.boxes, frame.gray.width as f32));
        if !self.busy && (self.due(frame) || (entering && self.at_side_edge_every_frame)) {
            self.send(frame);
            if self.busy && self.schedule.is_some() {
                self.pending = Some(frame.index);
            }
        }
        // old boxes are dropped, but (live, waiting allowed) not while a newer detection is on
        // its way: carried boxes keep the person out, none would let them into the map
        let on_its_way = self.busy && self.schedule.is_none() && self.max_wait_s > 0.0;
        match &self.latest {
            Some(l) if on_its_way || !self.stale(frame.index) => l.boxes.clone(),
            _ => Vec::new(),
        }
    }

    /// Whether the newest boxes hold an object of a class that moves on its own.
    fn mover_in_view(&self) -> bool {
        self.latest.as_ref().is_some_and(|l| {
            l.boxes
                .iter()
                .any(|d| self.movable_classes.contains(&d.class_id))
        })
    }

    /// Whether the newest boxes are too old to be carried to frame `index` (or there are none).
    fn stale(&self, index: usize) -> bool {
        self.latest
            .as_ref()
            .is_none_or(|l| index.saturating_sub(l.detected) > MAX_DETECTION_AGE)
    }

    /// Block until the detector returns the frame it holds, and take its boxes (`waiting`: the
    /// frame that waits, for the log).
    fn wait_for_detection(&mut self, waiting: usize) {
        self.wait_for_detection_at_most(waiting, None);
    }

    /// As [`BackgroundDetector::wait_for_detection`], but for at most `limit` (`None`: as long
    /// as it takes); nothing is taken when the detection does not come in time.
    fn wait_for_detection_at_most(&mut self, waiting: usize, limit: Option<std::time::Duration>) {
        if let Some(want) = self.in_flight.take() {
            // On a schedule (never a limit): the thread may return frames queued ahead first.
            loop {
                if let Some(result) = self.early.remove(&want) {
                    self.take((want, result));
                    return;
                }
                match self.thread.recv() {
                    Ok((index, result)) => {
                        self.early.insert(index, result);
                    }
                    Err(e) => {
                        self.busy = false;
                        tracing::warn!("frame {waiting}: detector failed: {e}");
                        return;
                    }
                }
            }
        }
        let done = match limit {
            None => self.thread.recv().map(Some),
            Some(limit) => self.thread.recv_timeout(limit),
        };
        match done {
            Ok(Some(done)) => self.take(done),
            Ok(None) => {}
            Err(e) => {
                self.busy = false;
                tracing::warn!("frame {waiting}: detector failed: {e}");
            }
        }
    }

    /// A finished detection becomes the newest boxes.
    fn take(&mut self, (detected, result): (usize, Result<Vec<Detection>, DetectError>)) {
        self.busy = false;
        let boxes = result.unwrap_or_else(|e| {
            tracing::warn!("frame {detected}: detector failed: {e}");
            Vec::new()
        });
        self.latest = Some(CarriedDetections {
            detected,
            at: detected,
            boxes,
        });
    }

    fn send(&mut self, frame: &FrameInput) {
        let handed = if self.schedule.is_some() {
            // The thread may have the frame already (queued ahead): then its boxes come
            // back, or have come, among the others.
            let queued = Arc::clone(&self.queued);
            let mut queued = queued.lock().unwrap_or_else(PoisonError::into_inner);
            let handed = queued.contains(&frame.index) || self.hand_over(frame);
            if handed {
                queued.insert(frame.index);
                self.in_flight = Some(frame.index);
            }
            handed
        } else {
            self.hand_over(frame)
        };
        if handed {
            self.busy = true;
            self.last_sent = Some(frame.timestamp);
        }
    }

    /// Queue `frame` with the thread; false (and a warning) when it cannot take it.
    fn hand_over(&self, frame: &FrameInput) -> bool {
        let rgb = detector_image(frame.gray, frame.rgb);
        match self.thread.send(frame.index, frame.timestamp, rgb) {
            Ok(()) => true,
            Err(e) => {
                tracing::warn!("frame {}: {e}", frame.index);
                false
            }
        }
    }

    /// The first frame: wait for its boxes.
    pub(crate) fn boxes_of_first(&mut self, frame: &FrameInput) -> Vec<Detection> {
        self.send(frame);
        if self.busy {
            self.wait_for_detection(frame.index);
        }
        self.boxes_detected_on(frame.index)
    }

    /// The newest boxes when they were detected on frame `index` itself, else none.
    fn boxes_detected_on(&self, index: usize) -> Vec<Detection> {
        match &self.latest {
            Some(l) if l.detected == index => l.boxes.clone(),
            _ => Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PERSON_CLASS;

    #[test]
    fn boxes_at_the_left_or_right_edge_are_told_apart() {
        let boxed = |x1: f32, x2: f32| {
            vec![Detection {
                bbox: stillpoint_geometry::BBox::new(x1, 100.0, x2, 300.0),
                class_id: PERSON_CLASS,
                score: 0.9,
            }]
        };
        assert!(at_side_edge(&boxed(0.0, 120.0), 640.0));
        assert!(at_side_edge(&boxed(3.5, 120.0), 640.0));
        assert!(at_side_edge(&boxed(500.0, 637.0), 640.0));
        assert!(!at_side_edge(&boxed(5.0, 634.0), 640.0));
        assert!(!at_side_edge(&[], 640.0));
    }
}
