//! Cross-crate: `stillpoint run` on a synthetic sequence that starts blank, has a run of black
//! frames and frames without depth must not abort, must recover, and must leave a valid TUM file.

use std::path::Path;
use std::process::Command;

fn stillpoint() -> Command {
    Command::new(env!("CARGO_BIN_EXE_stillpoint"))
}

fn blank(dir: &Path, stamp_file: &str, depth_too: bool) {
    let rgb = dir.join("rgb").join(stamp_file);
    let img = stillpoint_image::read_rgb(&rgb).unwrap();
    let black = stillpoint_image::Rgb8::new(img.width, img.height, [0, 0, 0]);
    stillpoint_image::write_rgb(&rgb, &black).unwrap();
    if depth_too {
        let d = dir.join("depth").join(stamp_file);
        let zero = stillpoint_image::ImageBuf::<u16>::new(img.width, img.height, 0);
        stillpoint_image::write_depth16(&d, &zero).unwrap();
    }
}

#[test]
fn blank_black_and_depthless_frames_do_not_abort() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    let st = stillpoint()
        .args(["synth", "--preset", "static", "--frames", "60", "--out"])
        .arg(&seq)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let mut names: Vec<String> = std::fs::read_dir(seq.join("rgb"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    // Blank start, a run of black frames, and frames whose depth is missing.
    for (i, n) in names.iter().enumerate() {
        if i < 3 || (25..30).contains(&i) {
            blank(&seq, n, true);
        } else if (40..43).contains(&i) {
            let zero = stillpoint_image::ImageBuf::<u16>::new(640, 480, 0);
            stillpoint_image::write_depth16(&seq.join("depth").join(n), &zero).unwrap();
        }
    }
    let traj = tmp.path().join("traj.txt");
    let out = stillpoint()
        .args([
            "run",
            "--detector",
            "none",
            "--sequential",
            "--json",
            "--dataset",
        ])
        .arg(&seq)
        .arg("--out")
        .arg(&traj)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let tracked = summary["tracked"].as_u64().unwrap();
    // 60 frames, 8 black: most of the rest must be tracked (recovery after the black run).
    assert!(tracked >= 45, "{summary}");
    let t = stillpoint_trajectory::read_tum(&traj).unwrap();
    assert_eq!(t.len() as u64, tracked);
    let ate = summary["ate"]["rmse"].as_f64().unwrap();
    assert!(ate < 0.02, "{summary}");
}
