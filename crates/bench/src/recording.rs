//! A recording processed as a user processes it, several times, side by side: each run is the
//! `stillpoint run` program itself, a process of its own (so its peak memory is its own), on
//! each backend asked for, with the machine idle and with a busy thread of this process beside
//! it. Per run: wall time, frames a second, how many times faster than the footage, peak
//! memory, ATE, and whether the trajectory is the same bytes as the backend's first run (a file
//! run is not a race: the load must not change it).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};

use serde::Serialize;

use crate::BenchError;

/// What is run, how, and how often.
#[derive(Clone, Debug)]
pub struct RecordingOptions {
    /// The `stillpoint` program to run (the command line passes itself).
    pub program: PathBuf,
    /// The recording: a sequence folder (as `run --dataset`).
    pub dataset: PathBuf,
    /// Its kind, when it cannot be told from the folder (`run --kind`).
    pub kind: Option<String>,
    /// Detector (`yolox`, `gt`, `none`); `None`: no front-end (`--no-dynamic`).
    pub detector: Option<String>,
    /// YOLOX ONNX model (else the default search).
    pub model: Option<PathBuf>,
    /// Detector backends, one run each a round (`detect.backend`); empty: the settings' own.
    pub backends: Vec<String>,
    /// Rounds; each runs every backend, idle and (with `busy`) loaded.
    pub rounds: usize,
    /// Also run each backend with a busy thread beside it.
    pub busy: bool,
    /// `--config` for every run.
    pub config: Option<PathBuf>,
    /// `--set` for every run (after `config`).
    pub sets: Vec<String>,
    /// Where the runs write their trajectories.
    pub out_dir: PathBuf,
}

/// One run.
#[derive(Clone, Debug, Serialize)]
pub struct RecordingRow {
    /// `detect.backend`, or "default".
    pub backend: String,
    /// Whether a busy thread ran beside it.
    pub busy: bool,
    /// Frames in the recording.
    pub frames: usize,
    /// Frames tracked.
    pub tracked: usize,
    /// Seconds from start to summary (the run's own `wall_s`).
    pub wall_s: f64,
    /// Frames a second.
    pub frames_per_second: f64,
    /// Frames a second of the footage (from its timestamps), when it has them.
    pub footage_fps: Option<f64>,
    /// Peak resident memory of the run's process, MiB.
    pub peak_memory_mib: Option<f64>,
    /// ATE RMSE, cm (with ground truth).
    pub ate_cm: Option<f64>,
    /// The trajectory file is the same bytes as this backend's first run's.
    pub same_trajectory: bool,
    /// ... and as the first run's of all (the first backend's).
    pub same_as_first_backend: bool,
}

impl RecordingRow {
    /// How many times faster than the footage was filmed (frames a second over the footage's).
    pub fn times_real_time(&self) -> Option<f64> {
        self.footage_fps
            .filter(|f| *f > 0.0)
            .map(|f| self.frames_per_second / f)
    }
}

/// Run the recording `o.rounds` times on every backend (idle, then loaded with `o.busy`);
/// `progress` sees each row. A run that fails stops the benchmark with its error line.
pub fn run_recording(
    o: &RecordingOptions,
    progress: &mut dyn FnMut(&RecordingRow),
) -> Result<Vec<RecordingRow>, BenchError> {
    if o.rounds == 0 {
        return Err(BenchError::Invalid("--rounds must be at least 1".into()));
    }
    std::fs::create_dir_all(&o.out_dir)
        .map_err(crate::io_error(format!("creating {}", o.out_dir.display())))?;
    let backends: Vec<Option<&str>> = if o.backends.is_empty() {
        vec![None]
    } else {
        o.backends.iter().map(|b| Some(b.as_str())).collect()
    };
    let loads: &[bool] = if o.busy { &[false, true] } else { &[false] };
    let mut first: Vec<Option<Vec<u8>>> = vec![None; backends.len()];
    let mut first_of_all: Option<Vec<u8>> = None;
    let mut rows = Vec::new();
    for round in 0..o.rounds {
        for (b, backend) in backends.iter().enumerate() {
            for &busy in loads {
                let name = format!("{}_{}_{round}", backend.unwrap_or("default"), load(busy));
                let traj = o.out_dir.join(format!("{name}.txt"));
                let summary = with_busy_thread(busy, || run_once(o, *backend, &traj))?;
                let bytes = std::fs::read(&traj)
                    .map_err(crate::io_error(format!("reading {}", traj.display())))?;
                let same = match &first[b] {
                    Some(f) => *f == bytes,
                    None => {
                        first[b] = Some(bytes.clone());
                        true
                    }
                };
                let same_as_first = *first_of_all.get_or_insert_with(|| bytes.clone()) == bytes;
                let row = row_of(
                    &summary,
                    backend.unwrap_or("default"),
                    busy,
                    &bytes,
                    (same, same_as_first),
                );
                progress(&row);
                rows.push(row);
            }
        }
    }
    Ok(rows)
}

fn load(busy: bool) -> &'static str {
    if busy { "busy" } else { "idle" }
}

/// `f()` with a thread of this process spinning beside it when `busy` (a second program
/// keeping one CPU busy, as a compiler or a browser would).
fn with_busy_thread<T>(busy: bool, f: impl FnOnce() -> T) -> T {
    if !busy {
        return f();
    }
    /// Stops the spinning thread however `f` ends (a panic too, or the scope would wait forever).
    struct StopOnDrop<'a>(&'a AtomicBool);
    impl Drop for StopOnDrop<'_> {
        fn drop(&mut self) {
            self.0.store(true, Ordering::Relaxed);
        }
    }
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        s.spawn(|| {
            while !stop.load(Ordering::Relaxed) {
                std::hint::spin_loop();
            }
        });
        let _stop = StopOnDrop(&stop);
        f()
    })
}

/// One `stillpoint run ... --json --out traj`; its JSON summary.
fn run_once(
    o: &RecordingOptions,
    backend: Option<&str>,
    traj: &Path,
) -> Result<serde_json::Value, BenchError> {
    let mut cmd = Command::new(&o.program);
    cmd.arg("run").arg("--dataset").arg(&o.dataset);
    if let Some(k) = &o.kind {
        cmd.args(["--kind", k]);
    }
    match &o.detector {
        Some(d) => cmd.args(["--detector", d]),
        None => cmd.arg("--no-dynamic"),
    };
    if let Some(m) = &o.model {
        cmd.arg("--model").arg(m);
    }
    if let Some(c) = &o.config {
        cmd.arg("--config").arg(c);
    }
    for s in &o.sets {
        cmd.args(["--set", s]);
    }
    if let Some(b) = backend {
        cmd.args(["--set", &format!("detect.backend={b}")]);
    }
    cmd.args(["--json", "--log", "warn", "--out"]).arg(traj);
    let what = format!(
        "{} run --dataset {}",
        o.program.display(),
        o.dataset.display()
    );
    let out = cmd
        .output()
        .map_err(crate::io_error(format!("starting {what}")))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let last = err
            .lines()
            .rev()
            .find(|l| !l.trim().is_empty())
            .unwrap_or("");
        return Err(BenchError::Invalid(format!(
            "{what} (backend {}) failed ({}): {last}",
            backend.unwrap_or("default"),
            out.status
        )));
    }
    serde_json::from_slice(&out.stdout)
        .map_err(|e| BenchError::Invalid(format!("{what}: its --json output is not JSON: {e}")))
}

fn row_of(
    s: &serde_json::Value,
    backend: &str,
    busy: bool,
    trajectory: &[u8],
    (same, same_as_first_backend): (bool, bool),
) -> RecordingRow {
    let f = |k: &str| s.get(k).and_then(|v| v.as_f64());
    let n = |k: &str| s.get(k).and_then(|v| v.as_u64()).unwrap_or(0) as usize;
    RecordingRow {
        backend: backend.to_string(),
        busy,
        frames: n("frames"),
        tracked: n("tracked"),
        wall_s: f("wall_s").unwrap_or(0.0),
        frames_per_second: f("frames_per_second").unwrap_or(0.0),
        footage_fps: footage_fps(trajectory),
        peak_memory_mib: f("peak_memory_mib"),
        ate_cm: s
            .get("ate")
            .and_then(|a| a.get("rmse"))
            .and_then(|v| v.as_f64())
            .map(|m| m * 100.0),
        same_trajectory: same,
        same_as_first_backend,
    }
}

/// Frames a second of the footage: one over the median gap between the timestamps of a TUM
/// trajectory (`t tx ty tz qx qy qz qw` lines, `#` comments); `None` with fewer than two.
pub fn footage_fps(trajectory: &[u8]) -> Option<f64> {
    let text = String::from_utf8_lossy(trajectory);
    let stamps: Vec<f64> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.split_whitespace().next()?.parse().ok())
        .collect();
    let mut gaps: Vec<f64> = stamps
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|g| *g > 0.0)
        .collect();
    if gaps.is_empty() {
        return None;
    }
    let mid = gaps.len() / 2;
    let (_, median, _) = gaps.select_nth_unstable_by(mid, f64::total_cmp);
    Some(1.0 / *median)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_footage_rate_is_one_over_the_median_gap() {
        let traj = b"# t tx ty tz qx qy qz qw\n\
            10.000 0 0 0 0 0 0 1\n10.0333 0 0 0 0 0 0 1\n10.0667 0 0 0 0 0 0 1\n\
            10.2000 0 0 0 0 0 0 1\n10.2333 0 0 0 0 0 0 1\n";
        let fps = footage_fps(traj).unwrap();
        assert!((fps - 30.0).abs() < 0.1, "{fps}");
        assert_eq!(footage_fps(b"10.0 0 0 0 0 0 0 1\n"), None);
        assert_eq!(footage_fps(b""), None);
    }

    #[test]
    fn a_row_reads_the_runs_summary() {
        let s = serde_json::json!({"frames": 300, "tracked": 299, "wall_s": 5.0,
            "frames_per_second": 60.0, "peak_memory_mib": 95.5, "ate": {"rmse": 0.0045}});
        let traj = b"0.0 0 0 0 0 0 0 1\n0.0333333 0 0 0 0 0 0 1\n0.0666667 0 0 0 0 0 0 1\n";
        let r = row_of(&s, "tract", true, traj, (true, false));
        assert_eq!((r.frames, r.tracked), (300, 299));
        assert_eq!(r.peak_memory_mib, Some(95.5));
        assert!((r.ate_cm.unwrap() - 0.45).abs() < 1e-9);
        assert!((r.times_real_time().unwrap() - 2.0).abs() < 1e-3);
        assert!(r.busy && r.same_trajectory && !r.same_as_first_backend);
    }

    #[test]
    fn a_program_that_fails_is_one_line_naming_the_run() {
        let dir = tempfile::tempdir().unwrap();
        let o = RecordingOptions {
            program: PathBuf::from("/bin/false"),
            dataset: dir.path().join("nothing"),
            kind: None,
            detector: Some("gt".into()),
            model: None,
            backends: vec![],
            rounds: 1,
            busy: false,
            config: None,
            sets: vec![],
            out_dir: dir.path().join("runs"),
        };
        let err = run_recording(&o, &mut |_| {}).unwrap_err().to_string();
        assert!(
            err.contains("/bin/false run --dataset") && err.contains("failed"),
            "{err}"
        );
        let none = RecordingOptions { rounds: 0, ..o };
        assert!(run_recording(&none, &mut |_| {}).is_err());
    }
}
