//! `run --overlay DIR`: a picture per frame, with the walkers' keypoints culled (red) and their
//! boxes judged moving, the static scene's keypoints kept (green or yellow).

mod common;
use common::stillpoint;

/// Pixels of exactly `colour` in an overlay.
fn count(img: &stillpoint_image::Rgb8, colour: [u8; 3]) -> usize {
    img.data.iter().filter(|&&p| p == colour).count()
}

#[test]
fn each_frame_gets_a_picture_with_culled_walkers_and_kept_background() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    let st = stillpoint()
        .args([
            "synth",
            "--preset",
            "walking_xyz",
            "--frames",
            "12",
            "--out",
        ])
        .arg(&seq)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let dir = tmp.path().join("overlay");
    let out = stillpoint()
        .args(["run", "--detector", "gt", "--sequential", "--dataset"])
        .arg(&seq)
        .arg("--out")
        .arg(tmp.path().join("traj.txt"))
        .arg("--overlay")
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    files.sort();
    assert_eq!(files.len(), 12, "{files:?}");
    assert_eq!(files[0], "000000.png");
    let last = stillpoint_image::read_rgb(&dir.join("000011.png")).unwrap();
    use stillpoint_run::overlay::{CULLED, KEPT, MATCHED};
    // Culled keypoints and moving boxes: red; tracked ones: green (matched) or yellow.
    assert!(count(&last, CULLED) > 100, "red {}", count(&last, CULLED));
    assert!(
        count(&last, MATCHED) + count(&last, KEPT) > 500,
        "green {} yellow {}",
        count(&last, MATCHED),
        count(&last, KEPT)
    );
}
