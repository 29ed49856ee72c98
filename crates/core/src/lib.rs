//! stillpoint-core: what every layer of stillpoint shares, one definition each: a frame as
//! the system receives it ([`Frame`]), what a sequence's images are ([`Sensor`], [`Settings`]:
//! the camera, frame rate, depth factor and the ORB extractor's sizes, [`OrbParams`]), summary
//! statistics of per-frame numbers ([`stats`]), a stage's time ([`ms_since`]) and a background
//! thread's priority ([`lower_this_thread_priority`]). Readers (`stillpoint-datasets`) sit above
//! it; the system (`stillpoint-pipeline`) takes its frames and settings from here.

#![deny(missing_docs)]

mod frame;
mod orb;
mod sensor;
pub mod stats;

pub use frame::Frame;
pub use orb::OrbParams;
pub use sensor::{Sensor, Settings};

use std::time::Instant;

/// Milliseconds since `t`: how long a stage took.
pub fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Lower the calling thread's priority by `nice` steps (Linux, where nice is per thread and
/// raising it needs no privileges; elsewhere nothing): work in the background (local mapping,
/// loop closing, a detector) must not take the cores from tracking, whose frames cannot wait.
pub fn lower_this_thread_priority(nice: i32) {
    #[cfg(target_os = "linux")]
    if nice > 0 {
        // SAFETY: syscalls on the calling thread's own id; on failure the priority stays.
        unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            let current = libc::getpriority(libc::PRIO_PROCESS, tid);
            let _ = libc::setpriority(libc::PRIO_PROCESS, tid, current + nice);
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = nice;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lowered_thread_runs_at_a_higher_nice_value() {
        std::thread::spawn(|| {
            #[cfg(target_os = "linux")]
            // SAFETY: reading the calling thread's own priority.
            let nice = || unsafe {
                libc::getpriority(
                    libc::PRIO_PROCESS,
                    libc::syscall(libc::SYS_gettid) as libc::id_t,
                )
            };
            #[cfg(target_os = "linux")]
            let before = nice();
            lower_this_thread_priority(3);
            #[cfg(target_os = "linux")]
            assert_eq!(nice(), (before + 3).min(19));
        })
        .join()
        .unwrap();
    }
}
