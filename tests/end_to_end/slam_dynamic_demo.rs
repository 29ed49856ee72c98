//! Cross-crate: `stillpoint demo` on a short synthetic walking_xyz sequence. The dynamic
//! front-end (gt boxes) must keep the trajectory within a centimetre and beat the baseline
//! without it. Bounds from measurements (90 frames, seed 0): off 10-40 cm until the map's
//! free-space check (points the depth image sees through leave the map) made the baseline
//! itself resist walkers: off 1.03 cm, on 0.47 cm (300 frames: 16.5 against 0.50 cm).
//! `--plots DIR`: both top views and the ATE over time, shaded where the generator's boxes
//! show a walker moving.

use std::process::Command;

#[test]
fn demo_front_end_on_beats_off_on_walking_xyz() {
    let tmp = tempfile::tempdir().unwrap();
    let (seq, plots) = (tmp.path().join("seq"), tmp.path().join("plots"));
    let out = Command::new(env!("CARGO_BIN_EXE_stillpoint"))
        .args([
            "demo", "--frames", "90", "--json", "--log", "warn", "--keep",
        ])
        .arg(&seq)
        .arg("--plots")
        .arg(&plots)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let off = summary["ate_rmse_off"].as_f64().unwrap();
    let on = summary["ate_rmse_on"].as_f64().unwrap();
    assert!(on < 0.01, "front-end on: ATE {on} m\n{summary}");
    assert!(on < 0.7 * off, "on {on} m vs off {off} m\n{summary}");
    let tracked = summary["on"]["tracked"].as_u64().unwrap();
    assert!(tracked >= 85, "{summary}");

    // The plots: PNGs of the expected sizes, listed in the summary.
    let (w, h) = stillpoint_trajectory::plot::ERROR_PLOT_SIZE;
    for (name, size) in [
        ("top_view_off.png", (900, 900)),
        ("top_view_on.png", (900, 900)),
        ("ate_over_time.png", (w as usize, h as usize)),
    ] {
        let path = plots.join(name);
        let img = stillpoint_image::read_rgb(&path).unwrap();
        assert_eq!((img.width, img.height), size, "{name}");
        let listed = summary["plots"].as_array().unwrap();
        assert!(
            listed.iter().any(|p| p == path.to_str().unwrap()),
            "{summary}"
        );
    }
    // The shaded periods span the frames whose boxes show a moving walker.
    let boxes = stillpoint_datasets::annotations::read_boxes(&seq.join("boxes.jsonl")).unwrap();
    let moving: Vec<f64> = boxes
        .iter()
        .filter(|f| f.boxes.iter().any(|b| b.moving))
        .map(|f| f.timestamp)
        .collect();
    let periods: Vec<(f64, f64)> =
        serde_json::from_value(summary["moving_periods"].clone()).unwrap();
    assert!(!periods.is_empty(), "{summary}");
    let half_frame = 0.5 / 30.0 + 1e-9;
    assert!(
        (periods[0].0 - (moving[0] - half_frame)).abs() < 1e-6,
        "{periods:?}"
    );
    let last = periods[periods.len() - 1].1;
    assert!(
        (last - (moving[moving.len() - 1] + half_frame)).abs() < 1e-6,
        "{periods:?}"
    );
    for t in &moving {
        assert!(
            periods.iter().any(|p| p.0 < *t && *t < p.1),
            "{t} {periods:?}"
        );
    }
}
