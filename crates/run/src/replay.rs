//! A sequence replayed at its timestamps, as a live camera delivers it (`run --realtime`).

use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

use stillpoint_datasets::{DatasetError, Frame, Sequence};

/// A replay at camera rate: what was processed, dropped and how late.
#[derive(Clone, Debug, Default)]
pub struct RealtimeReport {
    /// Frames the pipeline took.
    pub frames_processed: usize,
    /// Frames that arrived while the pipeline was busy and were overwritten by newer ones.
    pub frames_dropped: usize,
    /// Per processed frame: from the frame's arrival (its timestamp on the replay clock) to its
    /// pose, ms.
    pub latency_ms: Vec<f64>,
    /// Per processed frame: the pipeline's time on it, ms.
    pub processing_ms: Vec<f64>,
}

impl RealtimeReport {
    /// Latency median, p95 and max, ms (nearest rank).
    pub fn latency_quantiles(&self) -> [f64; 3] {
        let mut s = self.latency_ms.clone();
        s.sort_by(f64::total_cmp);
        [0.5, 0.95, 1.0].map(|q| stillpoint_core::stats::quantile(&s, q))
    }
}

/// One frame from the camera: its index, the frame (or why it could not be read), and when it
/// arrived.
pub(crate) type Arrival = (usize, Result<Frame, DatasetError>, Instant);

/// A camera replaying a sequence at its timestamps: frames are read ahead on their own thread
/// and handed over when due, through a channel. The consumer takes the newest frame waiting and
/// counts the ones it skips as dropped, as a live camera's driver would overwrite them.
pub(crate) struct ReplayCamera {
    frames: Receiver<Arrival>,
    pub(crate) dropped: usize,
}

impl ReplayCamera {
    /// Start replaying the first `n` frames of `seq`, each due at its timestamp or, with
    /// `rate_hz`, at `i / rate_hz`. When all of them fit in `preload_bytes` (judged by the first
    /// frame), they are decoded before the clock starts, as a camera hands over decoded frames;
    /// otherwise each is read just before it is due.
    pub(crate) fn start(
        seq: Box<dyn Sequence>,
        n: usize,
        preload_bytes: usize,
        rate_hz: Option<f64>,
    ) -> Self {
        // Unbounded: the camera never waits for the consumer (a bounded queue would hold it back
        // and hide drops); the consumer takes all that arrived each time, so it stays short.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("replay camera".into())
            .spawn(move || {
                let mut preloaded = preload(seq.as_ref(), n, preload_bytes);
                let start = Instant::now();
                let t0 = seq.timestamp(0).unwrap_or(0.0);
                for i in 0..n {
                    let frame = preloaded
                        .get_mut(i)
                        .and_then(Option::take)
                        .unwrap_or_else(|| seq.frame(i));
                    let since_first = match rate_hz {
                        Some(rate) => i as f64 / rate,
                        None => seq.timestamp(i).unwrap_or(t0 + i as f64 / 30.0) - t0,
                    };
                    let due = start + Duration::from_secs_f64(since_first.max(0.0));
                    let now = Instant::now();
                    // The camera's clock: a frame exists from its timestamp on.
                    if due > now {
                        std::thread::sleep(due - now);
                    }
                    if tx.send((i, frame, due.max(now))).is_err() {
                        break;
                    }
                }
            })
            .ok();
        Self {
            frames: rx,
            dropped: 0,
        }
    }

    /// The newest frame that has arrived (waiting for the next one when none has).
    pub(crate) fn next(&mut self) -> Option<Arrival> {
        let mut newest = self.frames.recv().ok()?;
        while let Ok(newer) = self.frames.try_recv() {
            self.dropped += 1;
            newest = newer;
        }
        Some(newest)
    }
}

/// Bytes a decoded frame holds.
fn frame_bytes(f: &Frame) -> usize {
    f.gray.data.len()
        + f.rgb.as_ref().map_or(0, |c| c.data.len() * 3)
        + f.depth.as_ref().map_or(0, |d| d.data.len() * 4)
        + f.right.as_ref().map_or(0, |r| r.data.len())
}

/// The first `n` frames of `seq` decoded, when `n` frames like the first fit in `max_bytes`;
/// else only the first (read to judge the size, and replayed as it is).
fn preload(
    seq: &dyn Sequence,
    n: usize,
    max_bytes: usize,
) -> Vec<Option<Result<Frame, DatasetError>>> {
    if n == 0 || max_bytes == 0 {
        return Vec::new();
    }
    let first = seq.frame(0);
    let per_frame = first.as_ref().map_or(0, frame_bytes).max(1);
    let mut frames = vec![Some(first)];
    if per_frame.saturating_mul(n) > max_bytes {
        return frames;
    }
    let t = Instant::now();
    frames.extend((1..n).map(|i| Some(seq.frame(i))));
    tracing::info!(
        "realtime: {n} frames decoded before the replay ({:.0} MiB, {:.1} s; `realtime.preload_mib`)",
        (per_frame * n) as f64 / (1024.0 * 1024.0),
        t.elapsed().as_secs_f64()
    );
    frames
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use stillpoint_datasets::{Sensor, Settings};
    use stillpoint_geometry::PinholeCamera;
    use stillpoint_image::Gray8;

    /// Frames of 8x8 gray at 1 kHz, counting the reads; from `ends_at` on, the source has
    /// ended (a video's last sample, a camera unplugged).
    struct Tiny {
        settings: Settings,
        n: usize,
        ends_at: usize,
        reads: Arc<AtomicUsize>,
    }

    impl Sequence for Tiny {
        fn settings(&self) -> &Settings {
            &self.settings
        }
        fn len(&self) -> usize {
            self.n
        }
        fn frame(&self, i: usize) -> Result<Frame, DatasetError> {
            self.reads.fetch_add(1, Ordering::SeqCst);
            if i >= self.ends_at {
                return Err(DatasetError::Ended {
                    path: "tiny".into(),
                    at: format!("frame {i}"),
                    msg: "unplugged".into(),
                });
            }
            Ok(Frame {
                index: i,
                timestamp: i as f64 / 1000.0,
                gray: Gray8::new(8, 8, i as u8),
                rgb: None,
                depth: None,
                right: None,
            })
        }
        fn ground_truth(&self) -> Option<std::path::PathBuf> {
            None
        }
        fn boxes(&self) -> Option<std::path::PathBuf> {
            None
        }
        fn name(&self) -> String {
            "tiny".into()
        }
        fn timestamp(&self, i: usize) -> Option<f64> {
            Some(i as f64 / 1000.0)
        }
    }

    pub(crate) fn tiny(n: usize) -> (Box<dyn Sequence>, Arc<AtomicUsize>) {
        tiny_ending(n, n)
    }

    /// [`tiny`], ended from frame `ends_at` on.
    pub(crate) fn tiny_ending(n: usize, ends_at: usize) -> (Box<dyn Sequence>, Arc<AtomicUsize>) {
        let camera = PinholeCamera::new(8.0, 8.0, 4.0, 4.0, 8, 8);
        let reads = Arc::new(AtomicUsize::new(0));
        let seq = Tiny {
            settings: Settings::with_camera(Sensor::Mono, camera),
            n,
            ends_at,
            reads: Arc::clone(&reads),
        };
        (Box::new(seq), reads)
    }

    #[test]
    fn a_sequence_that_fits_is_decoded_before_the_clock_starts_and_replayed_whole() {
        for (cap, preloads) in [(64 * 20, true), (64 * 20 - 1, false), (0, false)] {
            let (seq, reads) = tiny(20);
            let mut camera = ReplayCamera::start(seq, 20, cap, None);
            let (mut last, mut seen) = (None, 0);
            let first = camera.next().unwrap();
            if preloads {
                // Every frame was read before the first was handed over.
                assert_eq!(reads.load(Ordering::SeqCst), 20);
            }
            let mut arrival = Some(first);
            while let Some((i, frame, _)) = arrival {
                let frame = frame.unwrap();
                assert_eq!((frame.index, frame.gray.data[0] as usize), (i, i));
                assert!(last.is_none_or(|l| i > l));
                last = Some(i);
                seen += 1;
                arrival = camera.next();
            }
            assert_eq!(last, Some(19));
            assert_eq!(seen + camera.dropped, 20);
            // Each frame was read once, preloaded or not.
            assert_eq!(reads.load(Ordering::SeqCst), 20);
        }
    }

    #[test]
    fn latency_quantiles_rank_the_sorted_latencies() {
        let r = RealtimeReport {
            latency_ms: (1..=20).rev().map(f64::from).collect(),
            ..Default::default()
        };
        assert_eq!(r.latency_quantiles(), [11.0, 19.0, 20.0]);
        assert_eq!(RealtimeReport::default().latency_quantiles(), [0.0; 3]);
    }
}
