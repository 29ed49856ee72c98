//! `stillpoint run --save-map / --load-map / --localize` on synthetic sequences of one room.
//!
//! A map is made from one stretch of the `loop` preset's camera path and saved; a second
//! sequence of the same room (same scene seed, same world frame) from a later stretch of the
//! path is then localised in it. The map's frame is the first keyframe's camera (not the
//! generator's world frame), so the localisation run is scored in the map's frame: its poses
//! are carried into the world with the alignment of the mapping run to its ground truth, and
//! compared with the second sequence's ground truth without aligning again.

use crate::common::{error_line, ok_json, stillpoint};

use std::path::Path;
use stillpoint_synth::{Preset, SynthConfig, WriteOptions, tum_fr3_camera_sized};
use stillpoint_trajectory::{Alignment, AteOptions, Trajectory, ate, read_tum};

/// A `loop`-preset sequence at 320x240 of `frames` frames from `path_offset` seconds on.
fn synth(dir: &Path, frames: usize, path_offset: f64, size: (u32, u32)) {
    let cfg = SynthConfig {
        preset: Preset::Loop,
        frames,
        path_offset,
        camera: tum_fr3_camera_sized(size.0, size.1),
        ..SynthConfig::default()
    };
    let opts = WriteOptions {
        stereo: false,
        masks: false,
    };
    stillpoint_synth::write_sequence(&cfg, opts, dir).unwrap();
}

/// `stillpoint run --no-dynamic --sequential --json --dataset SEQ --out TRAJ` and `extra`.
fn run(seq: &Path, traj: &Path, extra: &[&std::ffi::OsStr]) -> std::process::Output {
    stillpoint()
        .args(["run", "--no-dynamic", "--sequential", "--json", "--dataset"])
        .arg(seq)
        .arg("--out")
        .arg(traj)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn a_second_sequence_localises_in_the_saved_map_and_leaves_it_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let (seq_a, seq_b) = (dir.path().join("a"), dir.path().join("b"));
    // Mapping: the first 5 s of the lap (a quarter of the room); localisation: 2 s from 1.5 s
    // on, inside the mapped stretch but on other poses.
    synth(&seq_a, 150, 0.0, (320, 240));
    synth(&seq_b, 60, 1.5, (320, 240));
    let map = dir.path().join("room.map");
    let (traj_a, traj_b) = (dir.path().join("a.txt"), dir.path().join("b.txt"));
    let mapped = ok_json(&run(
        &seq_a,
        &traj_a,
        &["--save-map".as_ref(), map.as_os_str()],
    ));
    let saved = &mapped["map_file"]["saved"];
    assert_eq!(saved["keyframes"], mapped["keyframes"], "{mapped}");
    assert_eq!(saved["map_points"], mapped["map_points"], "{mapped}");
    assert_eq!(
        saved["bytes"].as_u64(),
        Some(std::fs::metadata(&map).unwrap().len())
    );

    let localised = ok_json(&run(
        &seq_b,
        &traj_b,
        &[
            "--load-map".as_ref(),
            map.as_os_str(),
            "--localize".as_ref(),
        ],
    ));
    eprintln!(
        "mapping: {} keyframes, {} points; localisation: {localised}",
        mapped["keyframes"], mapped["map_points"]
    );
    // Relocalised at once, tracked throughout, and the map is as it was loaded.
    let first = localised["first_relocalisation"]
        .as_u64()
        .expect("relocalised");
    assert!(first <= 3, "first relocalised at frame {first}");
    assert_eq!(localised["tracked"].as_u64(), Some(60 - first));
    assert_eq!(localised["relocalisations"].as_u64(), Some(1));
    assert_eq!(localised["keyframes"], mapped["keyframes"]);
    assert_eq!(localised["map_points"], mapped["map_points"]);
    assert_eq!(
        localised["map_file"]["loaded"]["map_points"],
        mapped["map_points"]
    );

    // Accuracy in the map's frame.
    let gt = |seq: &Path| read_tum(&seq.join("groundtruth.txt")).unwrap();
    let aligned = AteOptions {
        align: Alignment::Se3,
        ..AteOptions::default()
    };
    let mapping = ate(&gt(&seq_a), &read_tum(&traj_a).unwrap(), &aligned).unwrap();
    let est = read_tum(&traj_b).unwrap();
    let in_world: Vec<_> = est
        .poses
        .iter()
        .map(|p| mapping.alignment.transform_pose(p))
        .collect();
    let in_world = Trajectory::from_parts(est.stamps.clone(), in_world).unwrap();
    let localisation = ate(&gt(&seq_b), &in_world, &AteOptions::default()).unwrap();
    eprintln!(
        "ATE mapping {:.4} m (own alignment), localisation {:.4} m (mapping's alignment)",
        mapping.stats.rmse, localisation.stats.rmse
    );
    assert_eq!(localisation.stats.count, est.len());
    assert!(
        localisation.stats.rmse <= mapping.stats.rmse,
        "localisation {} > mapping {}",
        localisation.stats.rmse,
        mapping.stats.rmse
    );
}

/// A DBoW2 text vocabulary of two words around `a` and `b`.
fn tiny_vocabulary(path: &Path, a: u8, b: u8) {
    let line = |d: u8, w: f32| {
        let bytes: Vec<String> = (0..32).map(|_| d.to_string()).collect();
        format!("0 1 {} {w}", bytes.join(" "))
    };
    let text = format!("2 1 0 0\n{}\n{}\n", line(a, 0.5), line(b, 2.0));
    std::fs::write(path, text).unwrap();
}

#[test]
fn maps_of_another_camera_vocabulary_or_format_are_refused_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let (seq, small) = (dir.path().join("seq"), dir.path().join("small"));
    synth(&seq, 20, 0.0, (320, 240));
    synth(&small, 3, 0.0, (160, 120));
    let (voc, other_voc) = (dir.path().join("voc.txt"), dir.path().join("other.txt"));
    tiny_vocabulary(&voc, 0, 255);
    tiny_vocabulary(&other_voc, 15, 240);
    let map = dir.path().join("m.map");
    let traj = dir.path().join("t.txt");
    ok_json(&run(
        &seq,
        &traj,
        &[
            "--save-map".as_ref(),
            map.as_os_str(),
            "--vocabulary".as_ref(),
            voc.as_os_str(),
        ],
    ));
    let load = |seq: &Path, map: &Path, extra: &[&std::ffi::OsStr]| {
        let mut args = vec!["--load-map".as_ref(), map.as_os_str()];
        args.extend_from_slice(extra);
        error_line(&run(seq, &traj, &args))
    };
    let name = map.display().to_string();
    // Another camera: both named.
    let e = load(&small, &map, &[]);
    assert!(
        e.contains(&name) && e.contains("camera") && e.contains("320x240") && e.contains("160x120"),
        "{e}"
    );
    // Another vocabulary: both fingerprints' sides named.
    let e = load(
        &seq,
        &map,
        &["--vocabulary".as_ref(), other_voc.as_os_str()],
    );
    assert!(e.contains(&name) && e.contains("vocabulary"), "{e}");
    // The map's own vocabulary is accepted (and tracking goes on in the map).
    let ok = ok_json(&run(
        &seq,
        &traj,
        &[
            "--load-map".as_ref(),
            map.as_os_str(),
            "--localize".as_ref(),
            "--vocabulary".as_ref(),
            voc.as_os_str(),
        ],
    ));
    assert!(ok["first_relocalisation"].as_u64().is_some(), "{ok}");

    let bytes = std::fs::read(&map).unwrap();
    let variant = |name: &str, f: &dyn Fn(&mut Vec<u8>)| {
        let p = dir.path().join(name);
        let mut b = bytes.clone();
        f(&mut b);
        std::fs::write(&p, b).unwrap();
        let e = load(&seq, &p, &[]);
        assert!(e.contains(&p.display().to_string()), "{e}");
        e
    };
    let e = variant("newer.map", &|b| {
        b[8..12].copy_from_slice(&2u32.to_le_bytes())
    });
    assert!(e.contains("version 2") && e.contains("newer"), "{e}");
    let e = variant("cut.map", &|b| b.truncate(b.len() / 2));
    assert!(e.contains("truncated"), "{e}");
    let e = variant("flipped.map", &|b| {
        let i = b.len() - 100;
        b[i] ^= 0x10;
    });
    assert!(e.contains("corrupted"), "{e}");
    let e = variant("other.map", &|b| {
        b[..8].copy_from_slice(b"\x89PNG\r\n\x1a\n")
    });
    assert!(e.contains("not a stillpoint map"), "{e}");
    let e = load(&seq, &dir.path().join("missing.map"), &[]);
    assert!(e.contains("missing.map"), "{e}");
}
