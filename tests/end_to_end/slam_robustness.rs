//! Cross-crate: `stillpoint run` on a synthetic sequence that starts blank, has a run of black
//! frames and frames without depth must not abort, must recover, and must leave a valid TUM file.

use std::path::Path;

use crate::common::synth_static;

/// File names in `dir`, sorted (the synth stamps sort in time order).
fn sorted_names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
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
    synth_static(&seq, 60, 0);
    let names = sorted_names(&seq.join("rgb"));
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
    let summary = run_without_detector(&seq, &traj);
    let tracked = summary["tracked"].as_u64().unwrap();
    // 60 frames, 8 black: most of the rest must be tracked (recovery after the black run).
    assert!(tracked >= 45, "{summary}");
    let t = stillpoint_trajectory::read_tum(&traj).unwrap();
    assert_eq!(t.len() as u64, tracked);
    let ate = summary["ate"]["rmse"].as_f64().unwrap();
    assert!(ate < 0.02, "{summary}");
}

/// Mirrors an image left to right in place.
fn mirror<T: Copy>(img: &mut stillpoint_image::ImageBuf<T>) {
    for y in 0..img.height {
        for x in 0..img.width / 2 {
            let (a, b) = (img.get(x, y), img.get(img.width - 1 - x, y));
            img.set(x, y, b);
            img.set(img.width - 1 - x, y, a);
        }
    }
}

/// Truly lost: 15 frames from another place spliced into a sequence: the same room with other
/// textures, mirrored left to right (the synthetic rooms share their geometry and camera path, so
/// unmirrored frames would agree with the map at the true pose, and tracking them is right).
/// Tracking must not follow the foreign frames onto the map, must come back by relocalisation
/// (or a new map) once the sequence returns, and the trajectory file must stay valid and
/// accurate.
#[test]
fn frames_from_another_place_are_lost_then_relocalised() {
    let tmp = tempfile::tempdir().unwrap();
    let (seq, other) = (tmp.path().join("seq"), tmp.path().join("other"));
    synth_static(&seq, 75, 0);
    synth_static(&other, 75, 7);
    let names = sorted_names(&seq.join("rgb"));
    let foreign = 30..45;
    for sub in ["rgb", "depth"] {
        let theirs = sorted_names(&other.join(sub));
        let ours = sorted_names(&seq.join(sub));
        for i in foreign.clone() {
            let (from, to) = (
                other.join(sub).join(&theirs[i]),
                seq.join(sub).join(&ours[i]),
            );
            if sub == "rgb" {
                let mut img = stillpoint_image::read_rgb(&from).unwrap();
                mirror(&mut img);
                stillpoint_image::write_rgb(&to, &img).unwrap();
            } else {
                let mut img = stillpoint_image::read_depth16(&from).unwrap();
                mirror(&mut img);
                stillpoint_image::write_depth16(&to, &img).unwrap();
            }
        }
    }
    let traj = tmp.path().join("traj.txt");
    let summary = run_without_detector(&seq, &traj);
    let recovered =
        summary["relocalisations"].as_u64().unwrap() + summary["new_maps"].as_u64().unwrap();
    assert!(recovered >= 1, "{summary}");
    let t = stillpoint_trajectory::read_tum(&traj).unwrap();
    assert_eq!(t.len() as u64, summary["tracked"].as_u64().unwrap());
    assert!(t.stamps.windows(2).all(|w| w[0] < w[1]), "stamps in order");
    // The frames of the sequence are tracked (all but a few around the splice) ...
    let stamp = |n: &str| n.trim_end_matches(".png").parse::<f64>().unwrap();
    let ours_tracked = names
        .iter()
        .enumerate()
        .filter(|(i, n)| {
            !foreign.contains(i) && t.stamps.iter().any(|s| (s - stamp(n)).abs() < 1e-4)
        })
        .count();
    assert!(
        ours_tracked >= 55,
        "{ours_tracked} of 60 tracked: {summary}"
    );
    // ... and the foreign ones, whose poses would be wrong, are not (at most a couple).
    let foreign_tracked = foreign
        .clone()
        .filter(|&i| t.stamps.iter().any(|s| (s - stamp(&names[i])).abs() < 1e-4))
        .count();
    assert!(
        foreign_tracked <= 2,
        "{foreign_tracked} foreign frames tracked: {summary}"
    );
    let ate = summary["ate"]["rmse"].as_f64().unwrap();
    assert!(ate < 0.02, "{summary}");
}

/// `stillpoint run --detector none --sequential --json` on `seq`; must succeed; its JSON summary.
fn run_without_detector(seq: &std::path::Path, traj: &std::path::Path) -> serde_json::Value {
    let out = crate::common::run_without_detector(seq, traj);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    serde_json::from_slice(&out.stdout).unwrap()
}
