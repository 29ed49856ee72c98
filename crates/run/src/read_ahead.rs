//! A recording's frames decoded ahead, in order, on a thread of their own (`read.ahead_frames`):
//! the pipeline's thread no longer waits for the PNG (or H.264) decoder between frames. Every
//! frame is still read and handed over, in order, so the run is the same as reading inline.

use std::path::PathBuf;
use std::sync::mpsc::{Receiver, Sender, channel, sync_channel};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Instant;

use stillpoint_datasets::{DatasetError, Frame, GroundTruthFormat, Sequence, Settings};
use stillpoint_pipeline::FramePrefetch;

use crate::replay::Arrival;

/// A sequence two threads share: the reader decodes frames from it, the run asks it for its
/// name, truth and stamps. What never changes is kept outside the lock.
struct SharedSequence {
    settings: Settings,
    len: usize,
    name: String,
    inner: Arc<Mutex<Box<dyn Sequence>>>,
}

impl SharedSequence {
    fn with<R>(&self, f: impl FnOnce(&dyn Sequence) -> R) -> R {
        let seq = self.inner.lock().unwrap_or_else(PoisonError::into_inner);
        f(seq.as_ref())
    }
}

impl Sequence for SharedSequence {
    fn settings(&self) -> &Settings {
        &self.settings
    }
    fn len(&self) -> usize {
        self.len
    }
    fn frame(&self, i: usize) -> Result<Frame, DatasetError> {
        self.with(|s| s.frame(i))
    }
    fn ground_truth(&self) -> Option<PathBuf> {
        self.with(|s| s.ground_truth())
    }
    fn ground_truth_format(&self) -> GroundTruthFormat {
        self.with(|s| s.ground_truth_format())
    }
    fn boxes(&self) -> Option<PathBuf> {
        self.with(|s| s.boxes())
    }
    fn name(&self) -> String {
        self.name.clone()
    }
    fn timestamp(&self, i: usize) -> Option<f64> {
        self.with(|s| s.timestamp(i))
    }
}

/// Frames `0..n` of a sequence, decoded up to `ahead` frames before the consumer takes them.
pub(crate) struct ReadAhead {
    frames: Receiver<(usize, Result<Frame, DatasetError>)>,
    /// Frames the run is done with, freed on the reader's thread: their buffers go back to
    /// that thread's cache of large blocks (`stillpoint_core::alloc`), where the next frame's
    /// decoding finds them; freed on the run's thread, each frame's were mapped afresh.
    done: Sender<Frame>,
}

impl ReadAhead {
    /// Start reading `seq`'s first `n` frames on a thread; the sequence comes back shared with
    /// that thread, for everything else the run asks of it. `None` when `ahead` is 0 (the
    /// sequence as it was) or the thread cannot be started (the sequence shared, with no one):
    /// the run then reads inline. Each frame decoded is offered to `prefetch` (the detector's
    /// schedule) before it is handed over.
    pub(crate) fn start(
        seq: Box<dyn Sequence>,
        n: usize,
        ahead: usize,
        prefetch: Option<FramePrefetch>,
    ) -> (Option<Self>, Box<dyn Sequence>) {
        if ahead == 0 {
            return (None, seq);
        }
        let shared = SharedSequence {
            settings: seq.settings().clone(),
            len: seq.len(),
            name: seq.name(),
            inner: Arc::new(Mutex::new(seq)),
        };
        // The channel holds `ahead - 1` frames and the reader one more, decoded and waiting
        // to be sent: `ahead` in all.
        let (tx, rx) = sync_channel(ahead - 1);
        let (done, spent) = channel::<Frame>();
        let reader = Arc::clone(&shared.inner);
        let spawned = std::thread::Builder::new()
            .name("frame reader".into())
            .spawn(move || {
                for i in 0..n {
                    while let Ok(frame) = spent.try_recv() {
                        drop(frame);
                    }
                    let frame = reader
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner)
                        .frame(i);
                    if let (Some(p), Ok(frame)) = (&prefetch, &frame) {
                        p.offer(frame);
                    }
                    let ended = matches!(frame, Err(DatasetError::Ended { .. }));
                    // A closed channel: the run stopped early.
                    if tx.send((i, frame)).is_err() || ended {
                        break;
                    }
                }
            });
        match spawned {
            Ok(_) => (Some(Self { frames: rx, done }), Box::new(shared)),
            Err(e) => {
                tracing::warn!("cannot start the frame reader ({e}); reading frames inline");
                (None, Box::new(shared))
            }
        }
    }

    /// The next frame in order, `None` once the reader has given all it will.
    pub(crate) fn next(&mut self) -> Option<Arrival> {
        let (i, frame) = self.frames.recv().ok()?;
        Some((i, frame, Instant::now()))
    }

    /// A frame the run is done with, to be freed where it was decoded.
    pub(crate) fn done_with(&self, frame: Frame) {
        // The reader has stopped: the frame is freed here.
        let _ = self.done.send(frame);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replay::tests::{tiny, tiny_ending};
    use std::sync::atomic::Ordering;

    #[test]
    fn frames_come_in_order_each_read_once_and_never_more_than_ahead_of_the_run() {
        for ahead in [1, 2, 3] {
            let (seq, reads) = tiny(20);
            let (reader, seq) = ReadAhead::start(seq, 20, ahead, None);
            let mut reader = reader.expect("a reader thread");
            for taken in 1..=20 {
                let (i, frame, _) = reader.next().expect("a frame");
                let frame = frame.unwrap();
                assert_eq!(
                    (i, frame.index, frame.gray.data[0] as usize),
                    (taken - 1, i, i)
                );
                let read = reads.load(Ordering::SeqCst);
                assert!(
                    read <= taken + ahead,
                    "ahead {ahead}: {read} read, {taken} taken"
                );
            }
            assert!(reader.next().is_none());
            assert_eq!(reads.load(Ordering::SeqCst), 20);
            // The run still asks the shared sequence what it is.
            assert_eq!((seq.len(), seq.name()), (20, "tiny".to_string()));
            assert_eq!(seq.timestamp(3), Some(0.003));
        }
    }

    #[test]
    fn no_reader_when_nothing_is_to_be_read_ahead() {
        let (seq, reads) = tiny(5);
        let (reader, seq) = ReadAhead::start(seq, 5, 0, None);
        assert!(reader.is_none());
        assert_eq!(reads.load(Ordering::SeqCst), 0);
        assert_eq!(seq.frame(2).unwrap().index, 2);
    }

    #[test]
    fn the_reader_stops_at_the_end_of_the_source() {
        let (seq, reads) = tiny_ending(20, 5);
        let (reader, _seq) = ReadAhead::start(seq, 20, 2, None);
        let mut reader = reader.expect("a reader thread");
        for i in 0..5 {
            assert!(reader.next().unwrap().1.is_ok(), "frame {i}");
        }
        let (i, ended, _) = reader.next().unwrap();
        assert!(
            matches!(ended, Err(DatasetError::Ended { .. })),
            "frame {i}"
        );
        assert!(reader.next().is_none());
        assert_eq!(reads.load(Ordering::SeqCst), 6);
    }
}
