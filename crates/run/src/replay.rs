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
        [0.5, 0.95, 1.0].map(|q| stillpoint_eval::quantile(&s, q))
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
    /// Start replaying the first `n` frames of `seq`.
    pub(crate) fn start(seq: Box<dyn Sequence>, n: usize) -> Self {
        // Unbounded: the camera never waits for the consumer (a bounded queue would hold it back
        // and hide drops); the consumer takes all that arrived each time, so it stays short.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("replay camera".into())
            .spawn(move || {
                let start = Instant::now();
                let t0 = seq.timestamp(0).unwrap_or(0.0);
                for i in 0..n {
                    let frame = seq.frame(i);
                    let t = seq.timestamp(i).unwrap_or(t0 + i as f64 / 30.0);
                    let due = start + Duration::from_secs_f64((t - t0).max(0.0));
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

#[cfg(test)]
mod tests {
    use super::*;

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
