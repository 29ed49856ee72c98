//! Live sources as a [`Sequence`]: a [`CaptureSource`] (a camera, a ROS 2 subscription, or in
//! tests frames fed from memory) read on its own thread, the frames handed over as
//! [`Sequence::frame`] asks.
//!
//! A live sequence has no known end: [`Sequence::len`] is `usize::MAX`, [`Sequence::frame`]
//! waits for the next frame and ignores the index it is given except to number the frame, and
//! the end of the stream (the source ends or fails) is a [`DatasetError::Ended`], after which a
//! run stops and keeps what it tracked. With [`Buffering::Newest`], as a camera driver does,
//! frames that arrive while the consumer is busy are overwritten by newer ones and counted as
//! dropped.

use crate::error::DatasetError;
use crate::sequence::Sequence;
use crate::{Frame, Settings};
use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::{Arc, Condvar, Mutex};
use stillpoint_image::{DepthMetres, Gray8, Rgb8, rgb_to_gray};

/// Something that delivers colour frames one after another.
pub trait FrameSource: Send + 'static {
    /// The next frame and its stamp (seconds); `Ok(None)` when the stream has ended. Blocks
    /// until a frame is there.
    fn next_frame(&mut self) -> Result<Option<(Rgb8, f64)>, DatasetError>;
    /// What to call the source in messages (`/dev/video0`).
    fn name(&self) -> String;
}

/// One frame as a live source delivers it: the colour image, and the depth image registered
/// to it (RGB-D) or the right image of a rectified pair (stereo).
#[derive(Clone, Debug)]
pub struct Captured {
    /// The colour (or only) image.
    pub rgb: Rgb8,
    /// Seconds.
    pub timestamp: f64,
    /// Metres, registered to `rgb`.
    pub depth: Option<DepthMetres>,
    /// The right image of a rectified pair.
    pub right: Option<Gray8>,
}

/// Something that delivers frames, colour with depth or a right image, one after another.
/// Every [`FrameSource`] is one.
pub trait CaptureSource: Send + 'static {
    /// The next frame; `Ok(None)` when the stream has ended. Blocks until a frame is there.
    fn next_capture(&mut self) -> Result<Option<Captured>, DatasetError>;
    /// What to call the source in messages.
    fn source_name(&self) -> String;
}

impl<T: FrameSource> CaptureSource for T {
    fn next_capture(&mut self) -> Result<Option<Captured>, DatasetError> {
        Ok(self.next_frame()?.map(|(rgb, timestamp)| Captured {
            rgb,
            timestamp,
            depth: None,
            right: None,
        }))
    }
    fn source_name(&self) -> String {
        self.name()
    }
}

/// What is kept of frames the consumer has not taken yet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Buffering {
    /// The newest frame only: older ones are dropped (a live camera: tracking works on the
    /// present, not on a backlog).
    Newest,
    /// Every frame, in order (a source that must not lose frames, such as a test's).
    All,
}

/// The hand-over between the reading thread and the consumer.
#[derive(Default)]
struct Slot {
    frames: VecDeque<Captured>,
    /// The stream ended (and, until the consumer has been told, why it failed).
    ended: bool,
    failure: Option<DatasetError>,
    dropped: usize,
    delivered: usize,
}

/// A [`CaptureSource`] read on its own thread.
pub struct LiveSequence {
    settings: Settings,
    name: String,
    shared: Arc<(Mutex<Slot>, Condvar)>,
}

impl LiveSequence {
    /// Start reading `source` on its own thread. `settings` describe its camera.
    pub fn start(
        mut source: Box<dyn CaptureSource>,
        settings: Settings,
        buffering: Buffering,
    ) -> Result<Self, DatasetError> {
        let name = source.source_name();
        let shared = Arc::new((Mutex::new(Slot::default()), Condvar::new()));
        let theirs = Arc::clone(&shared);
        std::thread::Builder::new()
            .name("live source".into())
            .spawn(move || {
                let (slot, ready) = &*theirs;
                loop {
                    let next = source.next_capture();
                    let mut s = slot.lock().unwrap_or_else(|e| e.into_inner());
                    match next {
                        Ok(Some(f)) => {
                            if buffering == Buffering::Newest && !s.frames.is_empty() {
                                s.dropped += s.frames.len();
                                s.frames.clear();
                            }
                            s.frames.push_back(f);
                        }
                        Ok(None) => s.ended = true,
                        Err(e) => (s.ended, s.failure) = (true, Some(e)),
                    }
                    let done = s.ended;
                    drop(s);
                    ready.notify_all();
                    if done {
                        break;
                    }
                }
            })
            .map_err(|e| DatasetError::Ended {
                path: name.clone(),
                at: "start".into(),
                msg: format!("cannot start its reading thread: {e}"),
            })?;
        Ok(Self {
            settings,
            name,
            shared,
        })
    }

    /// Frames overwritten before they were taken, and frames taken, so far.
    pub fn counts(&self) -> (usize, usize) {
        let s = self.shared.0.lock().unwrap_or_else(|e| e.into_inner());
        (s.dropped, s.delivered)
    }
}

impl Sequence for LiveSequence {
    fn settings(&self) -> &Settings {
        &self.settings
    }
    /// No known end.
    fn len(&self) -> usize {
        usize::MAX
    }
    /// The next frame (waiting for it), numbered `i`.
    fn frame(&self, i: usize) -> Result<Frame, DatasetError> {
        let (slot, ready) = &*self.shared;
        let mut s = slot.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if let Some(c) = s.frames.pop_front() {
                s.delivered += 1;
                drop(s);
                return Ok(Frame {
                    index: i,
                    timestamp: c.timestamp,
                    gray: rgb_to_gray(&c.rgb),
                    rgb: Some(c.rgb),
                    depth: c.depth,
                    right: c.right,
                });
            }
            if s.ended {
                return Err(s.failure.take().unwrap_or_else(|| DatasetError::Ended {
                    path: self.name.clone(),
                    at: format!("frame {i}"),
                    msg: format!("the stream ended after {} frames", s.delivered),
                }));
            }
            s = ready.wait(s).unwrap_or_else(|e| e.into_inner());
        }
    }
    fn ground_truth(&self) -> Option<PathBuf> {
        None
    }
    fn boxes(&self) -> Option<PathBuf> {
        None
    }
    fn name(&self) -> String {
        self.name
            .rsplit('/')
            .next()
            .unwrap_or(&self.name)
            .to_string()
    }
    fn timestamp(&self, _i: usize) -> Option<f64> {
        None
    }
}

/// A [`FrameSource`] fed from memory: the frames of a list, then the end (or an error). For
/// tests of the live path, and for replaying decoded frames as a camera.
pub struct MemorySource {
    frames: std::vec::IntoIter<(Rgb8, f64)>,
    then: Option<String>,
    name: String,
}

impl MemorySource {
    /// `frames` in order; after them the stream ends, or fails with `then`.
    pub fn new(name: &str, frames: Vec<(Rgb8, f64)>, then: Option<String>) -> Self {
        Self {
            frames: frames.into_iter(),
            then,
            name: name.to_string(),
        }
    }
}

impl FrameSource for MemorySource {
    fn next_frame(&mut self) -> Result<Option<(Rgb8, f64)>, DatasetError> {
        match (self.frames.next(), self.then.take()) {
            (Some(f), then) => {
                self.then = then;
                Ok(Some(f))
            }
            (None, None) => Ok(None),
            (None, Some(e)) => Err(DatasetError::Ended {
                path: self.name.clone(),
                at: "reading".into(),
                msg: e,
            }),
        }
    }
    fn name(&self) -> String {
        self.name.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Sensor;
    use stillpoint_geometry::PinholeCamera;

    fn frames(n: usize) -> Vec<(Rgb8, f64)> {
        (0..n)
            .map(|i| (Rgb8::new(4, 2, [i as u8; 3]), 100.0 + i as f64 / 30.0))
            .collect()
    }

    fn settings() -> Settings {
        Settings::with_camera(Sensor::Mono, PinholeCamera::new(4.0, 4.0, 2.0, 1.0, 4, 2))
    }

    #[test]
    fn every_frame_comes_in_order_then_the_end() {
        let src = MemorySource::new("/dev/fake0", frames(5), None);
        let seq = LiveSequence::start(Box::new(src), settings(), Buffering::All).unwrap();
        assert_eq!(seq.len(), usize::MAX);
        assert_eq!(seq.name(), "fake0");
        for i in 0..5 {
            let f = seq.frame(i).unwrap();
            assert_eq!((f.index, f.timestamp), (i, 100.0 + i as f64 / 30.0));
            assert_eq!(f.gray.data[0], i as u8);
        }
        let e = seq.frame(5).unwrap_err();
        assert!(matches!(e, DatasetError::Ended { .. }), "{e}");
        assert_eq!(
            e.to_string(),
            "/dev/fake0: frame 5: the stream ended after 5 frames"
        );
        assert_eq!(seq.counts(), (0, 5));
    }

    #[test]
    fn a_camera_keeps_the_newest_frame_and_counts_the_rest_dropped() {
        let src = MemorySource::new("cam", frames(50), Some("device unplugged".into()));
        let seq = LiveSequence::start(Box::new(src), settings(), Buffering::Newest).unwrap();
        let mut stamps = Vec::new();
        let err = loop {
            match seq.frame(stamps.len()) {
                Ok(f) => stamps.push(f.timestamp),
                Err(e) => break e,
            }
        };
        // However the threads interleave: stamps only go forward, the last frame is never
        // dropped (nothing overwrites it), and every frame is either taken or dropped.
        assert!(stamps.windows(2).all(|w| w[1] > w[0]), "{stamps:?}");
        assert_eq!(stamps.last(), Some(&(100.0 + 49.0 / 30.0)));
        let (dropped, delivered) = seq.counts();
        assert_eq!((dropped + delivered, delivered), (50, stamps.len()));
        assert_eq!(err.to_string(), "cam: reading: device unplugged");
    }
}
