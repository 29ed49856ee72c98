//! Bad input gives one clear error naming the file and line; random input never panics.

use proptest::prelude::*;
use stillpoint_geometry::Se3;
use stillpoint_trajectory::{
    Trajectory, TrajectoryError, TrajectoryFormat, TumWriter, parse, parse_euroc, parse_kitti,
    parse_tum, read_kitti, read_trajectory_lenient, read_tum, write_kitti, write_tum,
};

fn err(text: &str) -> String {
    parse_tum(text.as_bytes(), "est.txt")
        .unwrap_err()
        .to_string()
}

#[test]
fn tum_errors_name_file_and_line() {
    let good = "# comment\n\n1.0 0 0 0 0 0 0 1\n";
    assert_eq!(parse_tum(good.as_bytes(), "est.txt").unwrap().len(), 1);
    let e = err("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n");
    assert!(e.starts_with("est.txt:2:") && e.contains("found 7"), "{e}");
    let e = err("1.0 0 0 x 0 0 0 1\n");
    assert!(
        e.starts_with("est.txt:1:") && e.contains("\"x\" is not a number"),
        "{e}"
    );
    let e = err("1.0 0 0 NaN 0 0 0 1\n");
    assert!(
        e.starts_with("est.txt:1:") && e.contains("not a finite"),
        "{e}"
    );
    let e = err("2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n");
    assert!(e.starts_with("est.txt:2:") && e.contains("sorted"), "{e}");
    let e = err("1.0 0 0 0 0 0 0 1\n\n1.0 0 0 0 0 0 0 1\n");
    assert!(
        e.starts_with("est.txt:3:") && e.contains("duplicate"),
        "{e}"
    );
    let e = err("1.0 0 0 0 0 0 0 0\n");
    assert!(e.contains("zero length"), "{e}");
    assert!(matches!(
        parse_tum(b"# only comments\n", "e.txt"),
        Err(TrajectoryError::Empty { .. })
    ));
    assert_eq!(
        parse_tum(b"", "e.txt").unwrap_err().to_string(),
        "e.txt: no poses in file"
    );
}

#[test]
fn lenient_reading_keeps_duplicates_and_reports_their_lines() {
    let text = b"1.0 0 0 0 0 0 0 1\n1.0 1 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n";
    let (t, dups) = parse(text, "gt.txt", TrajectoryFormat::Tum, true).unwrap();
    assert_eq!((t.len(), dups), (3, vec![2]));
    let e = parse(
        b"2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n",
        "gt.txt",
        TrajectoryFormat::Tum,
        true,
    );
    assert!(e.is_err());
}

#[test]
fn kitti_and_euroc_errors() {
    let id = "1 0 0 0 0 1 0 0 0 0 1 0\n";
    assert_eq!(
        parse_kitti(id.repeat(3).as_bytes(), "p.txt")
            .unwrap()
            .stamps,
        vec![0.0, 1.0, 2.0]
    );
    let e = parse_kitti(b"1 0 0 0 0 1 0 0 0 0 1\n", "p.txt")
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("p.txt:1:") && e.contains("found 11"), "{e}");
    let e = parse_kitti(b"2 0 0 0 0 1 0 0 0 0 1 0\n", "p.txt")
        .unwrap_err()
        .to_string();
    assert!(e.contains("not a rotation"), "{e}");
    let csv = "#timestamp, x\n1000000000,1,2,3,1,0,0,0,9\n2000000000,1,2,3,1,0,0,0\n";
    let t = parse_euroc(csv.as_bytes(), "gt.csv").unwrap();
    assert_eq!(t.stamps, vec![1.0, 2.0]);
    let e = parse_euroc(b"1,2,3\n", "gt.csv").unwrap_err().to_string();
    assert!(e.starts_with("gt.csv:1:"), "{e}");
}

#[test]
fn files_roundtrip_and_missing_file_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let poses: Vec<Se3> = (0..5)
        .map(|i| {
            Se3::new(
                [i as f64, 0.5, -1.0].into(),
                [0.1 * i as f64, 0.2, 0.0].into(),
            )
        })
        .collect();
    let traj =
        Trajectory::from_parts((0..5).map(|i| 100.0 + i as f64 / 30.0).collect(), poses).unwrap();
    let tum = dir.path().join("a.txt");
    write_tum(&tum, &traj).unwrap();
    let back = read_tum(&tum).unwrap();
    assert_eq!(back.stamps, traj.stamps);
    for (a, b) in back.poses.iter().zip(&traj.poses) {
        assert!((a.inverse() * b).translation.vector.norm() < 1e-12);
    }
    let kitti = dir.path().join("k.txt");
    write_kitti(&kitti, &traj).unwrap();
    assert_eq!(read_kitti(&kitti).unwrap().len(), 5);
    // The writer flushes every line: the file is complete before the writer is dropped.
    let live = dir.path().join("live.txt");
    let mut w = TumWriter::create(&live).unwrap();
    for (t, p) in traj.stamps.iter().zip(&traj.poses) {
        w.write(*t, p).unwrap();
    }
    assert_eq!(read_tum(&live).unwrap().len(), 5);
    // A whole-file write over it (as after a loop correction) replaces it whole, through a
    // sibling file that does not stay behind.
    let shorter =
        Trajectory::from_parts(traj.stamps[..3].to_vec(), traj.poses[..3].to_vec()).unwrap();
    write_tum(&live, &shorter).unwrap();
    assert_eq!(read_tum(&live).unwrap().len(), 3);
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        3,
        "a.txt, k.txt, live.txt"
    );
    drop(w);
    let missing = dir.path().join("nope.txt");
    let e = read_trajectory_lenient(&missing, TrajectoryFormat::Tum)
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope.txt"), "{e}");
}

proptest! {
    #[test]
    fn parsers_never_panic_on_random_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        for f in [TrajectoryFormat::Tum, TrajectoryFormat::Kitti, TrajectoryFormat::Euroc] {
            let _ = parse(&bytes, "r", f, false);
            let _ = parse(&bytes, "r", f, true);
        }
    }

    #[test]
    fn parsers_never_panic_on_numberish_lines(
        lines in proptest::collection::vec(
            proptest::collection::vec(
                prop_oneof![
                    any::<f64>().prop_map(|v| v.to_string()),
                    Just("nan".to_string()), Just("-inf".to_string()), Just("1e309".to_string()),
                    Just("#".to_string()), Just(",".to_string()), Just("".to_string()),
                    (-1.0f64..1.0).prop_map(|v| v.to_string()),
                ],
                0..14,
            ),
            0..12,
        ),
        comma in any::<bool>(),
    ) {
        let sep = if comma { "," } else { " " };
        let text: String = lines.iter().map(|l| l.join(sep) + "\n").collect();
        for f in [TrajectoryFormat::Tum, TrajectoryFormat::Kitti, TrajectoryFormat::Euroc] {
            if let Ok((t, _)) = parse(text.as_bytes(), "r", f, true) {
                prop_assert!(!t.is_empty());
                prop_assert!(t.stamps.windows(2).all(|w| w[0] <= w[1]));
            }
        }
    }
}
