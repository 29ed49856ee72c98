//! `stillpoint eval` end to end: synthetic trajectories written to a temp dir, the binary run on
//! them; bad input gives a non-zero exit and one error line naming the file and line.

use std::path::{Path, PathBuf};
use std::process::Command;

fn stillpoint(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_stillpoint"))
        .args(args)
        .output()
        .expect("run stillpoint")
}

/// Ground truth on a circle; the estimate is the ground truth shifted by 0.1 m in z and scaled.
fn write_pair(dir: &Path) -> (PathBuf, PathBuf) {
    let (mut gt, mut est) = (String::new(), String::new());
    for i in 0..200 {
        let t = 100.0 + i as f64 / 30.0;
        let a = i as f64 * 0.05;
        let (x, y) = (a.cos(), a.sin());
        gt.push_str(&format!("{t} {x} {y} 1.0 0 0 0 1\n"));
        est.push_str(&format!(
            "{} {} {} 1.6 0 0 0 1\n",
            t + 0.001,
            0.5 * x,
            0.5 * y
        ));
    }
    let (g, e) = (dir.join("gt.txt"), dir.join("est.txt"));
    std::fs::write(&g, gt).unwrap();
    std::fs::write(&e, est).unwrap();
    (g, e)
}

fn json(out: &std::process::Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON object on stdout")
}

#[test]
fn ate_rpe_json_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let (g, e) = write_pair(dir.path());
    let (g, e) = (g.to_str().unwrap(), e.to_str().unwrap());
    let none = json(&stillpoint(&[
        "eval", "ate", "--gt", g, "--est", e, "--json",
    ]));
    assert_eq!(none["count"], 200);
    assert!(none["rmse"].as_f64().unwrap() > 0.3);
    let plot = dir.path().join("top.svg");
    let sim3 = json(&stillpoint(&[
        "eval",
        "ate",
        "--gt",
        g,
        "--est",
        e,
        "--align",
        "sim3",
        "--json",
        "--plot",
        plot.to_str().unwrap(),
    ]));
    assert!(sim3["rmse"].as_f64().unwrap() < 1e-9, "{sim3}");
    assert!((sim3["scale"].as_f64().unwrap() - 2.0).abs() < 1e-9);
    assert!(plot.exists());
    for key in [
        "count", "rmse", "mean", "median", "std", "min", "max", "sse",
    ] {
        assert!(sim3.get(key).is_some(), "missing {key}");
    }
    // The estimate is the truth at another scale throughout: every piece's scale is the run's.
    let along = &sim3["scale_along_path"];
    let ratios = along["ratios"].as_array().expect("scale along the path");
    assert_eq!(ratios.len(), 10, "{along}");
    assert!(
        ratios
            .iter()
            .all(|q| (q.as_f64().unwrap() - 1.0).abs() < 1e-9)
    );
    assert!(along["drift"].as_f64().unwrap().abs() < 1e-9, "{along}");
    let r = json(&stillpoint(&[
        "eval",
        "rpe",
        "--gt",
        g,
        "--est",
        e,
        "--align",
        "sim3",
        "--delta",
        "10",
        "--delta-unit",
        "f",
        "--json",
    ]));
    assert_eq!(r["translation"]["count"], 19);
    assert!(r["rotation_deg"]["max"].as_f64().unwrap() < 1e-6);
    let table = stillpoint(&["eval", "ate", "--gt", g, "--est", e]);
    assert!(String::from_utf8_lossy(&table.stdout).contains("rmse"));
    let table = stillpoint(&["eval", "ate", "--gt", g, "--est", e, "--align", "sim3"]);
    let table = String::from_utf8_lossy(&table.stdout).into_owned();
    assert!(
        table.contains("scale drift, end to end: ") && table.contains("0.0 %"),
        "{table}"
    );
}

#[test]
fn bad_input_fails_with_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let (g, _) = write_pair(dir.path());
    let bad = dir.path().join("bad.txt");
    std::fs::write(&bad, "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n").unwrap();
    let out = stillpoint(&[
        "eval",
        "ate",
        "--gt",
        g.to_str().unwrap(),
        "--est",
        bad.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.txt:2:") && err.contains("found 7"),
        "{err}"
    );
    let out = stillpoint(&[
        "eval",
        "ate",
        "--gt",
        "/nonexistent/gt.txt",
        "--est",
        bad.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/gt.txt"));
}

#[test]
fn ate_over_time_plot_with_moving_periods() {
    let dir = tempfile::tempdir().unwrap();
    let (g, e) = write_pair(dir.path());
    let (g, e) = (g.to_str().unwrap(), e.to_str().unwrap());
    let moving = dir.path().join("moving.txt");
    std::fs::write(&moving, "# start end\n101.0 102.5\n104 105\n").unwrap();
    let plot = dir.path().join("ate.png");
    let args = [
        "eval",
        "ate",
        "--gt",
        g,
        "--est",
        e,
        "--align",
        "se3",
        "--json",
        "--time-plot",
    ];
    let out = stillpoint(
        &[
            &args[..],
            &[plot.to_str().unwrap(), "--moving", moving.to_str().unwrap()],
        ]
        .concat(),
    );
    json(&out);
    let img = stillpoint_image::read_rgb(&plot).unwrap();
    let (w, h) = stillpoint_trajectory::plot::ERROR_PLOT_SIZE;
    assert_eq!((img.width, img.height), (w as usize, h as usize));
    // Without periods: a plot all the same; a bad periods file or a folder without boxes: one
    // error naming it.
    json(&stillpoint(
        &[&args[..], &[plot.to_str().unwrap()]].concat(),
    ));
    std::fs::write(&moving, "101 102\n103 oops\n").unwrap();
    let out = stillpoint(
        &[
            &args[..],
            &[plot.to_str().unwrap(), "--moving", moving.to_str().unwrap()],
        ]
        .concat(),
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("moving.txt:2:"), "{err}");
    let out = stillpoint(
        &[
            &args[..],
            &[
                plot.to_str().unwrap(),
                "--dataset",
                dir.path().to_str().unwrap(),
            ],
        ]
        .concat(),
    );
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no boxes.jsonl"));
}
