//! `stillpoint run --camera DEVICE` without a camera there: one error line naming the device and
//! a non-zero exit, no trajectory file. A file that is not a camera is refused as such with the
//! `camera` feature (V4L2), and without it the line says how to build with camera support.

use crate::common::{error_line, stillpoint};

fn run_camera(device: &std::path::Path, traj: &std::path::Path) -> std::process::Output {
    stillpoint()
        .args(["run", "--detector", "none", "--camera"])
        .arg(device)
        .arg("--out")
        .arg(traj)
        .output()
        .unwrap()
}

#[test]
fn a_missing_or_wrong_camera_device_is_one_error_line_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let traj = tmp.path().join("traj.txt");

    let missing = tmp.path().join("video9");
    let out = run_camera(&missing, &traj);
    assert_eq!(out.status.code(), Some(1));
    let e = error_line(&out);
    assert!(
        e.contains(&format!("{}: opening: no such camera", missing.display())),
        "{e}"
    );
    assert!(!traj.exists());

    let not_a_camera = tmp.path().join("notacam");
    std::fs::write(&not_a_camera, b"").unwrap();
    let e = error_line(&run_camera(&not_a_camera, &traj));
    assert!(
        e.contains(&format!("{}: opening: ", not_a_camera.display())),
        "{e}"
    );
    if cfg!(feature = "camera") {
        assert!(e.contains("not a V4L2 camera"), "{e}");
    } else {
        assert!(e.contains("--features camera"), "{e}");
    }
    assert!(!traj.exists());
}
