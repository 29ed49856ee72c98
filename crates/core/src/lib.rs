//! stillpoint-core: what every layer of stillpoint shares, one definition each: a frame as
//! the system receives it ([`Frame`]), what a sequence's images are ([`Sensor`], [`Settings`]:
//! the camera, frame rate, depth factor and the ORB extractor's sizes, [`OrbParams`]), summary
//! statistics of per-frame numbers ([`stats`]), a stage's time ([`ms_since`]), the process's
//! memory ([`memory_mib`]), a background
//! thread's priority ([`lower_this_thread_priority`]) and the program's allocator (`alloc`,
//! Linux). Readers (`stillpoint-datasets`) sit above
//! it; the system (`stillpoint-pipeline`) takes its frames and settings from here.

#![deny(missing_docs)]

#[cfg(target_os = "linux")]
pub mod alloc;
mod frame;
mod orb;
mod sensor;
pub mod stats;

pub use frame::Frame;
pub use orb::OrbParams;
pub use sensor::{Sensor, Settings};

use std::time::Instant;

/// Resident and peak resident memory of this process in MiB (`VmRSS`, `VmHWM` of
/// `/proc/self/status`; `None` where there is none): what a run reports as its memory.
pub fn memory_mib() -> (Option<f64>, Option<f64>) {
    let Ok(status) = std::fs::read_to_string("/proc/self/status") else {
        return (None, None);
    };
    let field = |name: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|v| v.split_whitespace().next()?.parse::<f64>().ok())
            .map(|kib| kib / 1024.0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

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

/// Keep the calling thread, and every thread it starts from now on, to the first `n` CPUs it
/// may run on (Linux; elsewhere an error): a benchmark's stand-in for a smaller machine. Returns
/// the CPUs kept.
pub fn pin_this_thread_to_first_cpus(n: usize) -> Result<Vec<usize>, String> {
    #[cfg(target_os = "linux")]
    // SAFETY: `cpu_set_t` is plain data, zeroed then filled with the CPU_* helpers; the
    // syscalls act on the calling thread (pid 0) and report failure by their return value.
    unsafe {
        let mut allowed: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut allowed) != 0 {
            return Err(format!(
                "sched_getaffinity: {}",
                std::io::Error::last_os_error()
            ));
        }
        let cpus: Vec<usize> = (0..libc::CPU_SETSIZE as usize)
            .filter(|&c| libc::CPU_ISSET(c, &allowed))
            .take(n)
            .collect();
        if n == 0 || cpus.len() < n {
            return Err(format!("{n} CPUs asked, {} available", cpus.len()));
        }
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        for &c in &cpus {
            libc::CPU_SET(c, &mut set);
        }
        if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
            return Err(format!(
                "sched_setaffinity: {}",
                std::io::Error::last_os_error()
            ));
        }
        Ok(cpus)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = n;
        Err("pinning to CPUs needs Linux".into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pinned_thread_and_its_children_run_on_the_first_cpu() {
        std::thread::spawn(|| {
            let kept = pin_this_thread_to_first_cpus(1);
            #[cfg(target_os = "linux")]
            {
                let kept = kept.expect("one CPU");
                assert_eq!(kept.len(), 1);
                // a thread started afterwards inherits the mask
                let child = std::thread::spawn(|| pin_this_thread_to_first_cpus(2))
                    .join()
                    .unwrap();
                assert!(child.is_err(), "only one CPU is left to the child");
            }
            #[cfg(not(target_os = "linux"))]
            assert!(kept.is_err());
        })
        .join()
        .unwrap();
    }

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
