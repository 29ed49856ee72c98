//! `stillpoint settings` and `run --config/--set`: the effective tree with sources, and errors
//! that name the file and line or the override, with a non-zero exit.

use crate::common::stillpoint;

#[test]
fn settings_shows_each_value_with_its_source() {
    let tmp = tempfile::tempdir().unwrap();
    let config = tmp.path().join("mine.toml");
    std::fs::write(&config, "[front_end]\norb_exclusion = true\n").unwrap();
    let out = stillpoint()
        .args(["settings", "--config"])
        .arg(&config)
        .args(["--set", "slam.kf_weak_tracking_inliers=40"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let from_file = format!("front_end.orb_exclusion = true  # {}:2", config.display());
    assert!(text.lines().any(|l| l == from_file), "{text}");
    assert!(
        text.lines()
            .any(|l| l == "slam.kf_weak_tracking_inliers = 40  # --set")
    );
    assert!(
        text.lines()
            .any(|l| l == "front_end.dynamic.world.enabled = true  # default")
    );
}

#[test]
fn an_unknown_key_stops_run_before_any_frame_naming_file_and_line() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    let st = stillpoint()
        .args(["synth", "--preset", "static", "--frames", "3", "--out"])
        .arg(&seq)
        .output()
        .unwrap();
    assert!(st.status.success());
    let config = tmp.path().join("typo.toml");
    std::fs::write(
        &config,
        "[front_end.dynamic.world]\nenabled = true\ninlier_pix = 3.0\n",
    )
    .unwrap();
    let out = stillpoint()
        .args(["run", "--detector", "none", "--dataset"])
        .arg(&seq)
        .arg("--config")
        .arg(&config)
        .arg("--out")
        .arg(tmp.path().join("t.txt"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    let expected = format!(
        "{}:3: unknown key `front_end.dynamic.world.inlier_pix`",
        config.display()
    );
    assert!(err.contains(&expected), "{err}");
    let out = stillpoint()
        .args(["settings", "--set", "orb.n_features=many"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("--set orb.n_features=many: `orb.n_features`")
    );
}
