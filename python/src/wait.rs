//! Long calls without the GIL that Ctrl-C still interrupts, and panics turned into exceptions.

use std::panic::AssertUnwindSafe;
use std::sync::mpsc::RecvTimeoutError;
use std::time::Duration;

use pyo3::prelude::*;

use crate::Error;

/// The message a panic carried.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

/// `work` with the GIL released; a panic in it is a `stillpoint.Error`.
pub fn detached<T: Send>(py: Python<'_>, work: impl FnOnce() -> T + Send) -> PyResult<T> {
    py.detach(|| std::panic::catch_unwind(AssertUnwindSafe(work)))
        .map_err(|p| Error::new_err(format!("internal error: {}", panic_message(&*p))))
}

/// `work` on its own thread with the GIL released, Python's signal handlers checked every 50 ms:
/// Ctrl-C raises `KeyboardInterrupt` at once (the work ends in the background and its result is
/// dropped). A panic in it is a `stillpoint.Error`.
pub fn interruptible<T: Send + 'static>(
    py: Python<'_>,
    work: impl FnOnce() -> T + Send + 'static,
) -> PyResult<T> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name("stillpoint-call".into())
        .spawn(move || {
            let _ = tx.send(std::panic::catch_unwind(AssertUnwindSafe(work)));
        })
        .map_err(|e| Error::new_err(format!("starting a thread: {e}")))?;
    let mut rx = rx;
    loop {
        // The receiver goes with the wait and comes back (it is Send, not Sync).
        let (got, back) = py.detach(move || (rx.recv_timeout(Duration::from_millis(50)), rx));
        rx = back;
        match got {
            Ok(Ok(v)) => return Ok(v),
            Ok(Err(p)) => {
                return Err(Error::new_err(format!(
                    "internal error: {}",
                    panic_message(&*p)
                )));
            }
            Err(RecvTimeoutError::Timeout) => py.check_signals()?,
            Err(RecvTimeoutError::Disconnected) => {
                return Err(Error::new_err(
                    "internal error: the call ended without a result",
                ));
            }
        }
    }
}
