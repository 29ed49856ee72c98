//! A recording is not a race: `stillpoint run` on a file, in its default mode, gives the
//! trajectory of `--sequential` byte for byte while other threads keep both cores busy (a
//! compiler, a browser, a second run on the user's machine). Monocular suffered most: a mapper
//! that fell behind left tracking without the last keyframes' points, and the run lost its map.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::common::{assert_ok, path_str, shared, shared_yolox, stillpoint, synth_walking};
use crate::slam_mono::synth_mono;

/// Threads that spin until dropped: one per core, so the run under test shares them.
struct Busy {
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<u64>>,
}

impl Busy {
    fn start() -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
        let threads = (0..cores)
            .map(|i| {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let mut x = i as u64 + 1;
                    while !stop.load(Ordering::Relaxed) {
                        x = std::hint::black_box(x.wrapping_mul(6_364_136_223_846_793_005) + 1);
                    }
                    x
                })
            })
            .collect();
        Self { stop, threads }
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// `stillpoint run --json --dataset SEQ --out TRAJ EXTRA..`: the trajectory file's bytes and the
/// JSON summary.
fn run(seq: &Path, traj: &Path, extra: &[&str]) -> (Vec<u8>, serde_json::Value) {
    let out = stillpoint()
        .args([
            "run",
            "--json",
            "--dataset",
            path_str(seq),
            "--out",
            path_str(traj),
        ])
        .args(extra)
        .output()
        .unwrap();
    assert_ok(&out);
    let summary = serde_json::from_slice(&out.stdout).unwrap();
    (std::fs::read(traj).unwrap(), summary)
}

/// The default run under load against `--sequential` on an idle machine, `extra` for both.
fn same_as_sequential_under_load(seq: &Path, extra: &[&str]) -> serde_json::Value {
    same_as_sequential_under_load_in(seq, seq.parent().unwrap(), extra)
}

/// [`same_as_sequential_under_load`], the trajectories written to `dir`.
fn same_as_sequential_under_load_in(seq: &Path, dir: &Path, extra: &[&str]) -> serde_json::Value {
    let mut sequential = vec!["--sequential"];
    sequential.extend_from_slice(extra);
    let (expected, _) = run(seq, &dir.join("sequential.txt"), &sequential);
    let busy = Busy::start();
    let (got, summary) = run(seq, &dir.join("default.txt"), extra);
    drop(busy);
    assert!(
        expected == got,
        "{}: the default run's trajectory differs from --sequential's: {summary}",
        seq.display()
    );
    summary
}

#[test]
fn a_monocular_file_run_on_a_busy_machine_is_the_sequential_run() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("mono");
    synth_mono(&seq, 60);
    let summary = same_as_sequential_under_load(&seq, &["--detector", "none"]);
    assert_eq!(summary["sensor"], "mono", "{summary}");
    assert!(summary["tracked"].as_u64().unwrap() >= 30, "{summary}");
}

/// Real hand-held video with people (SAM 2's bedroom frames, monocular) and YOLOX: the reader
/// hands each frame on the detector's schedule to the detector as it decodes it, ahead of
/// tracking, and the boxes wait for their frame's turn; `--sequential` reads each frame only
/// when its turn comes. The map starts on frames that wait for their own boxes, among them.
#[test]
#[ignore = "needs ../shared/data"]
fn a_monocular_recording_with_yolox_on_a_busy_machine_is_the_sequential_run() {
    let seq = shared().join("data/video/sam2_bedroom/rgb");
    let model = shared_yolox();
    let tmp = tempfile::tempdir().unwrap();
    let summary = same_as_sequential_under_load_in(
        &seq,
        tmp.path(),
        &["--frames", "45", "--model", path_str(&model)],
    );
    assert_eq!(summary["sensor"], "mono", "{summary}");
    assert!(summary["tracked"].as_u64().unwrap() >= 40, "{summary}");
    // People are boxed: the front-end culls their keypoints.
    assert!(
        summary["culled_per_frame"]["mean"].as_f64().unwrap() > 0.0,
        "{summary}"
    );
}

#[test]
fn an_rgbd_file_run_with_the_front_end_on_a_busy_machine_is_the_sequential_run() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("walking");
    synth_walking(&seq, 90, &[]);
    let summary = same_as_sequential_under_load(&seq, &["--detector", "gt"]);
    assert_eq!(summary["sensor"], "rgbd", "{summary}");
    assert_eq!(summary["tracked"], 90, "{summary}");
    // The speed a user compares with the footage's frame rate: frames over the run's wall time.
    let wall_s = summary["wall_s"].as_f64().unwrap();
    let per_second = summary["frames_per_second"].as_f64().unwrap();
    assert!(wall_s > 0.0, "{summary}");
    assert!((per_second * wall_s - 90.0).abs() < 1e-6, "{summary}");
    // And what it took of memory (Linux: the process's peak resident size).
    #[cfg(target_os = "linux")]
    assert!(
        summary["peak_memory_mib"].as_f64().unwrap() > 1.0,
        "{summary}"
    );
    // The mapping thread is still there for whoever asks for it (a camera, `--realtime`).
    let (_, threaded) = run(
        &seq,
        &tmp.path().join("threaded.txt"),
        &[
            "--detector",
            "gt",
            "--set",
            "slam.local_mapping_thread=true",
        ],
    );
    let rows = threaded["timing"].as_object().unwrap();
    assert!(
        rows.contains_key("tracking: waiting for the map"),
        "{threaded}"
    );
}

#[test]
fn a_stereo_file_run_with_the_front_end_on_a_busy_machine_is_the_sequential_run() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("walking");
    // The KITTI-layout pair beside the TUM folder; `--kind kitti` reads it as stereo, the
    // generator's boxes from the same folder.
    synth_walking(&seq, 60, &["--stereo"]);
    let summary = same_as_sequential_under_load(&seq, &["--kind", "kitti", "--detector", "gt"]);
    assert_eq!(summary["sensor"], "stereo", "{summary}");
    assert_eq!(summary["tracked"], 60, "{summary}");
}

#[test]
fn bench_recording_runs_the_program_idle_and_loaded_and_finds_one_trajectory() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("walking");
    synth_walking(&seq, 40, &[]);
    let out = stillpoint()
        .args(["bench", "recording", "--dataset", path_str(&seq)])
        .args([
            "--detector",
            "gt",
            "--rounds",
            "1",
            "--busy",
            "--json",
            "--out",
        ])
        .arg(tmp.path().join("runs"))
        .output()
        .unwrap();
    assert_ok(&out);
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let runs = report["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2, "{report}");
    assert_eq!(runs[0]["busy"], false, "{report}");
    assert_eq!(runs[1]["busy"], true, "{report}");
    for r in runs {
        assert_eq!(r["tracked"], 40, "{report}");
        assert_eq!(r["same_trajectory"], true, "{report}");
        // The generator's frames are 30 a second apart.
        assert!(
            (r["footage_fps"].as_f64().unwrap() - 30.0).abs() < 0.1,
            "{report}"
        );
        #[cfg(target_os = "linux")]
        assert!(r["peak_memory_mib"].as_f64().unwrap() > 1.0, "{report}");
    }
    // Both trajectories are there to compare by hand.
    assert!(tmp.path().join("runs/default_busy_0.txt").is_file());
}
