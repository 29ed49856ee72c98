//! [`DetectorThread`]: a detector on its own thread. Frames go in over a channel, boxes come
//! back over another, tagged with the frame index. The model is loaded once, on that thread;
//! the caller blocks on `recv` (no polling); dropping the handle stops and joins the thread.

use crate::{DetectError, DetectInput, Detection, Detector};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::Duration;
use stillpoint_image::Rgb8;

/// Boxes of one frame, or the error detecting it, with the frame's index.
pub type DetectOutput = (usize, Result<Vec<Detection>, DetectError>);

struct Job {
    index: usize,
    timestamp: f64,
    rgb: Arc<Rgb8>,
}

/// Handle to a running detector thread.
///
/// ```
/// use stillpoint_detect::{DetectorThread, NoDetector};
/// let worker = DetectorThread::spawn(|| Ok(Box::new(NoDetector) as _)).unwrap();
/// worker.send(7, 0.5, stillpoint_image::Rgb8::new(4, 4, [0; 3])).unwrap();
/// let (index, boxes) = worker.recv().unwrap();
/// assert_eq!(index, 7);
/// assert!(boxes.unwrap().is_empty());
/// ```
pub struct DetectorThread {
    jobs: JobQueue,
    results: Receiver<DetectOutput>,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
    name: String,
}

impl DetectorThread {
    /// Start the thread and build the detector on it with `make` (so the model is loaded once,
    /// where it runs). Returns when the detector is ready, or with the error that prevented it.
    pub fn spawn<F>(make: F) -> Result<Self, DetectError>
    where
        F: FnOnce() -> Result<Box<dyn Detector>, DetectError> + Send + 'static,
    {
        let (job_tx, job_rx) = mpsc::channel::<Job>();
        let (out_tx, out_rx) = mpsc::channel::<DetectOutput>();
        let (ready_tx, ready_rx) = mpsc::channel::<Result<String, DetectError>>();
        let stop = Arc::new(AtomicBool::new(false));
        let stop_worker = Arc::clone(&stop);
        let handle = std::thread::Builder::new()
            .name("detector".into())
            .spawn(move || {
                let mut detector = match make() {
                    Ok(d) => {
                        let _ = ready_tx.send(Ok(d.name().to_string()));
                        d
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                // Ends when the handle drops its sender (or sets `stop`).
                while let Ok(job) = job_rx.recv() {
                    if stop_worker.load(Ordering::Relaxed) {
                        break;
                    }
                    let result = detector.detect(&DetectInput {
                        index: job.index,
                        timestamp: job.timestamp,
                        rgb: &job.rgb,
                    });
                    if out_tx.send((job.index, result)).is_err() {
                        break;
                    }
                }
            })
            .map_err(|e| DetectError::ThreadStopped(format!("cannot start: {e}")))?;
        let name = match ready_rx.recv() {
            Ok(Ok(name)) => name,
            Ok(Err(e)) => {
                let _ = handle.join();
                return Err(e);
            }
            Err(_) => {
                let _ = handle.join();
                return Err(DetectError::ThreadStopped(
                    "the detector panicked while loading".into(),
                ));
            }
        };
        Ok(Self {
            jobs: JobQueue(Arc::new(Mutex::new(Some(job_tx)))),
            results: out_rx,
            stop,
            handle: Some(handle),
            name,
        })
    }

    /// Queue a frame. Returns at once; the boxes come back through [`Self::recv`].
    pub fn send(
        &self,
        index: usize,
        timestamp: f64,
        rgb: impl Into<Arc<Rgb8>>,
    ) -> Result<(), DetectError> {
        self.jobs.send(index, timestamp, rgb.into())
    }

    /// A handle that queues frames from another thread (a recording's reader, frames ahead of
    /// the caller); their boxes come back through [`Self::recv`] among the caller's. It queues
    /// nothing once this handle is dropped.
    pub fn queue(&self) -> JobQueue {
        self.jobs.clone()
    }

    /// Wait for the next result (in the order frames were sent).
    pub fn recv(&self) -> Result<DetectOutput, DetectError> {
        self.results
            .recv()
            .map_err(|_| DetectError::ThreadStopped("the detector thread has exited".into()))
    }

    /// Wait at most `timeout` for the next result; `Ok(None)` when none came in time.
    pub fn recv_timeout(&self, timeout: Duration) -> Result<Option<DetectOutput>, DetectError> {
        match self.results.recv_timeout(timeout) {
            Ok(out) => Ok(Some(out)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(DetectError::ThreadStopped(
                "the detector thread has exited".into(),
            )),
        }
    }

    /// A result if one is ready, without waiting.
    pub fn try_recv(&self) -> Option<DetectOutput> {
        self.results.try_recv().ok()
    }

    /// The detector's name (`"yolox-tract"`, `"gt"`, ...).
    pub fn name(&self) -> &str {
        &self.name
    }
}

/// Frames into a [`DetectorThread`], from any thread ([`DetectorThread::queue`]).
#[derive(Clone)]
pub struct JobQueue(Arc<Mutex<Option<Sender<Job>>>>);

impl JobQueue {
    /// Queue a frame; an error once the detector thread is stopped.
    pub fn send(&self, index: usize, timestamp: f64, rgb: Arc<Rgb8>) -> Result<(), DetectError> {
        let job = Job {
            index,
            timestamp,
            rgb,
        };
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .as_ref()
            .ok_or_else(|| DetectError::ThreadStopped("shut down".into()))?
            .send(job)
            .map_err(|_| DetectError::ThreadStopped("the detector thread has exited".into()))
    }

    /// Close the queue for every handle: the thread ends after its frame in progress.
    fn close(&self) {
        self.0.lock().unwrap_or_else(PoisonError::into_inner).take();
    }
}

impl std::fmt::Debug for JobQueue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("JobQueue")
    }
}

impl Drop for DetectorThread {
    /// Skip queued frames, close the queue and wait for the frame in progress to finish.
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        self.jobs.close();
        if let Some(handle) = self.handle.take()
            && handle.join().is_err()
        {
            tracing::warn!("detector thread panicked");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::BBox;
    use std::sync::atomic::AtomicUsize;

    /// Returns one box whose x1 is the frame index; counts how often it was built.
    struct Echo;
    impl Detector for Echo {
        fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
            if input.rgb.is_empty() {
                return Err(DetectError::BadInput("empty".into()));
            }
            Ok(vec![Detection {
                class_id: 0,
                score: 1.0,
                bbox: BBox::new(input.index as f32, 0.0, 1.0, 1.0),
            }])
        }
        fn name(&self) -> &str {
            "echo"
        }
    }

    #[test]
    fn frames_in_order_loaded_once_errors_passed_back() {
        static BUILT: AtomicUsize = AtomicUsize::new(0);
        let worker = DetectorThread::spawn(|| {
            BUILT.fetch_add(1, Ordering::SeqCst);
            Ok(Box::new(Echo) as Box<dyn Detector>)
        })
        .unwrap();
        assert_eq!(worker.name(), "echo");
        for i in 0..5 {
            worker.send(i, i as f64, Rgb8::new(2, 2, [0; 3])).unwrap();
        }
        worker.send(99, 0.0, Rgb8::new(0, 0, [0; 3])).unwrap();
        for i in 0..5 {
            let (index, boxes) = worker.recv().unwrap();
            assert_eq!(index, i);
            assert_eq!(boxes.unwrap()[0].bbox.x1, i as f32);
        }
        let (index, err) = worker.recv().unwrap();
        assert_eq!(index, 99);
        assert!(err.is_err());
        assert!(worker.try_recv().is_none());
        assert!(
            worker
                .recv_timeout(Duration::from_millis(1))
                .unwrap()
                .is_none()
        );
        assert_eq!(BUILT.load(Ordering::SeqCst), 1);
        drop(worker); // joins; a hang here would fail the test run
    }

    #[test]
    fn load_errors_come_back_from_spawn() {
        let err = DetectorThread::spawn(|| Err(DetectError::BadInput("no model".into())));
        assert!(err.err().unwrap().to_string().contains("no model"));
        let panicked = DetectorThread::spawn(|| panic!("boom"));
        assert!(matches!(panicked, Err(DetectError::ThreadStopped(_))));
    }

    #[test]
    fn drop_with_queued_frames_returns() {
        let worker = DetectorThread::spawn(|| Ok(Box::new(Echo) as Box<dyn Detector>)).unwrap();
        for i in 0..100 {
            worker.send(i, 0.0, Rgb8::new(64, 64, [0; 3])).unwrap();
        }
        drop(worker);
    }
}
