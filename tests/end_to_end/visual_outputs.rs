//! `run --overlay DIR`: a picture per frame, with the walkers' keypoints culled (red) and their
//! boxes judged moving, the static scene's keypoints kept (green or yellow); `--map-cloud FILE`:
//! the map's points as a PLY cloud; `--dense-cloud FILE`: keyframe depth without the walkers.

use crate::common::{ok_json, stillpoint, synth_walking};

/// Pixels of exactly `colour` in an overlay.
fn count(img: &stillpoint_image::Rgb8, colour: [u8; 3]) -> usize {
    img.data.iter().filter(|&&p| p == colour).count()
}

#[test]
fn each_frame_gets_a_picture_and_the_map_a_point_cloud() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth_walking(&seq, 12, &["--masks"]);
    let dir = tmp.path().join("overlay");
    let out = stillpoint()
        .args(["run", "--detector", "gt", "--sequential", "--dataset"])
        .arg(&seq)
        .arg("--out")
        .arg(tmp.path().join("traj.txt"))
        .arg("--overlay")
        .arg(&dir)
        .arg("--map-cloud")
        .arg(tmp.path().join("map.ply"))
        .arg("--dense-cloud")
        .arg(tmp.path().join("dense.ply"))
        .arg("--json")
        .output()
        .unwrap();
    let summary = ok_json(&out);
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

    // The cloud holds the map's points, each a line after the header.
    let ply = std::fs::read_to_string(tmp.path().join("map.ply")).unwrap();
    let (header, body) = ply.split_once("end_header\n").unwrap();
    let n = summary["map_points"].as_u64().unwrap() as usize;
    assert!(n > 100, "{summary}");
    assert!(
        header.contains(&format!("element vertex {n}\n")),
        "{header}"
    );
    assert_eq!(body.lines().count(), n);
    for line in body.lines() {
        let v: Vec<f64> = line.split(' ').map(|x| x.parse().unwrap()).collect();
        assert_eq!(v.len(), 4, "{line}");
        assert!(v[2].abs() < 20.0 && v[3] >= 1.0, "{line}");
    }
    // The dense cloud: what two keyframes both saw of the room, the walkers left out.
    let dense = std::fs::read_to_string(tmp.path().join("dense.ply")).unwrap();
    let points = summary["dense_points"].as_u64().unwrap();
    assert!(points > 1_000, "{summary}");
    assert!(dense.contains(&format!("element vertex {points}\n")));
    let on_movers = summary["dense_points_on_movers"].as_u64().unwrap();
    assert!(
        on_movers * 1000 <= points,
        "{on_movers} of {points} on the walkers"
    );
}
