//! What the command-line tests share: the binary and its plainest run.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use stillpoint_synth::{Preset, SynthConfig, WriteOptions};

/// The `stillpoint` binary under test.
pub fn stillpoint() -> Command {
    Command::new(env!("CARGO_BIN_EXE_stillpoint"))
}

/// `stillpoint run --detector none --json --dataset SEQ --out TRAJ` (the default mode, which on
/// a file is `--sequential`'s, `file_runs.rs`).
pub fn run_without_detector(seq: &Path, traj: &Path) -> Output {
    run_without_detector_on(&["--dataset", path_str(seq)], traj)
}

/// `stillpoint run --detector none --json SOURCE.. --out TRAJ`, the source being
/// `--dataset D` or `--bag F --rgb-topic ..`.
pub fn run_without_detector_on(source: &[&str], traj: &Path) -> Output {
    stillpoint()
        .args(["run", "--detector", "none", "--json"])
        .args(source)
        .arg("--out")
        .arg(traj)
        .output()
        .unwrap()
}

/// [`run_without_detector_on`] a recording, `--bag bag`, with the topic flags `topics`.
pub fn run_without_detector_on_bag(bag: &Path, topics: &[&str], traj: &Path) -> Output {
    let mut source = vec!["--bag", path_str(bag)];
    source.extend_from_slice(topics);
    run_without_detector_on(&source, traj)
}

/// A path as the `&str` argument lists want (the tests' temporary paths are UTF-8).
pub fn path_str(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `../shared` beside the workspace, or `$STILLPOINT_SHARED`.
pub fn shared() -> PathBuf {
    std::env::var_os("STILLPOINT_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared"))
}

/// The shared YOLOX-nano 480x640 model, for a test that cannot do without it.
pub fn shared_yolox() -> PathBuf {
    let model = shared().join("models/yolox_nano_480x640.onnx");
    assert!(model.is_file(), "needs the YOLOX model {}", model.display());
    model
}

/// `stillpoint synth --preset static --frames N --seed S --out DIR`; must succeed.
pub fn synth_static(dir: &Path, frames: usize, seed: u64) {
    let st = stillpoint()
        .args(["synth", "--preset", "static", "--frames"])
        .arg(frames.to_string())
        .arg("--seed")
        .arg(seed.to_string())
        .arg("--out")
        .arg(dir)
        .output()
        .unwrap();
    assert_ok(&st);
}

/// `stillpoint synth --preset walking_xyz --frames N [EXTRA...] --out DIR`; must succeed.
pub fn synth_walking(dir: &Path, frames: usize, extra: &[&str]) {
    synth_preset(dir, "walking_xyz", frames, extra);
}

/// `stillpoint synth --preset PRESET --frames N [EXTRA...] --out DIR`; must succeed.
pub fn synth_preset(dir: &Path, preset: &str, frames: usize, extra: &[&str]) {
    let st = stillpoint()
        .args(["synth", "--preset", preset, "--frames"])
        .arg(frames.to_string())
        .args(extra)
        .arg("--out")
        .arg(dir)
        .output()
        .unwrap();
    assert_ok(&st);
}

/// A synthetic static sequence whose depth PNGs hold millimetres (factor 1000), as a 16UC1
/// recording does, so the folder and the recording hold the same depth values.
pub fn synth_in_millimetres(dir: &Path, frames: usize) {
    let cfg = SynthConfig {
        preset: Preset::Static,
        frames,
        ..Default::default()
    };
    let opts = WriteOptions {
        stereo: false,
        masks: false,
    };
    stillpoint_synth::write_sequence(&cfg, opts, dir).unwrap();
    let settings_file = dir.join("settings.toml");
    let mut settings = stillpoint_datasets::read_settings_toml(&settings_file).unwrap();
    let factor = settings.depth_factor;
    for e in std::fs::read_dir(dir.join("depth")).unwrap() {
        let p = e.unwrap().path();
        let mut raw = stillpoint_image::read_depth16(&p).unwrap();
        for v in &mut raw.data {
            *v = (f64::from(*v) * 1000.0 / factor).round() as u16;
        }
        stillpoint_image::write_depth16(&p, &raw).unwrap();
    }
    settings.depth_factor = 1000.0;
    stillpoint_datasets::write_settings_toml(&settings_file, &settings).unwrap();
}

/// Two TUM trajectory files hold the same stamps and poses (to 1e-9).
pub fn assert_same_trajectory(a: &Path, b: &Path) {
    let (ta, tb) = (
        stillpoint_trajectory::read_tum(a).unwrap(),
        stillpoint_trajectory::read_tum(b).unwrap(),
    );
    assert_eq!(ta.len(), tb.len());
    for (i, ((sa, pa), (sb, pb))) in ta
        .stamps
        .iter()
        .zip(&ta.poses)
        .zip(tb.stamps.iter().zip(&tb.poses))
        .enumerate()
    {
        assert_eq!(sa, sb, "pose {i}: stamps");
        let d = pa.inverse() * pb;
        assert!(
            d.translation.vector.norm() < 1e-9 && d.rotation.angle() < 1e-9,
            "pose {i}: {pa:?} vs {pb:?}"
        );
    }
}

/// The one error line of a failed command (`error: ...`), with no panic.
pub fn error_line(out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error")).collect();
    assert_eq!(errors.len(), 1, "{stderr}");
    errors[0].to_string()
}

/// The command succeeded (its stderr in the failure message).
pub fn assert_ok(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The JSON summary of a command that succeeded.
pub fn ok_json(out: &Output) -> serde_json::Value {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {stderr}"))
}
