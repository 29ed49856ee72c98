//! Property tests of the readers users hand files to: settings (ORB-SLAM YAML, stillpoint
//! TOML) and stamped lists (TUM `rgb.txt` / `depth.txt`, association files, KITTI `times.txt`,
//! and a TUM folder opened whole). Each property feeds arbitrary bytes or a mutated valid file:
//! the reader returns `Ok` or an error naming the file, never panics, and what it accepts is
//! sane.
//!
//! `cargo test` runs 256 cases a property. The `#[ignore]`d `long_*` variants run
//! `STILLPOINT_FUZZ_CASES` cases a property (default 20,000):
//! `STILLPOINT_FUZZ_CASES=200000 cargo test -p stillpoint-datasets --test fuzz_readers -- --ignored --nocapture`.

use proptest::prelude::*;
use proptest::test_runner::Config;
use stillpoint_datasets::{
    DatasetKind, Sensor, associate_nearest, open, read_associations, read_settings,
    read_stamped_list, read_times, write_settings_toml,
};

/// Cases of the `long_*` variants: `STILLPOINT_FUZZ_CASES`, default 20,000.
fn long_cases() -> u32 {
    std::env::var("STILLPOINT_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20_000)
}

fn config(cases: u32) -> Config {
    Config {
        cases,
        // Failures are printed with their input; no files are left beside the sources.
        failure_persistence: None,
        ..Config::default()
    }
}

/// ORB-SLAM2's `Examples/RGB-D/TUM1.yaml`, as shipped (comments shortened).
const TUM1_YAML: &str = "%YAML:1.0

# Camera calibration and distortion parameters (OpenCV)
Camera.fx: 517.306408
Camera.fy: 516.469215
Camera.cx: 318.643040
Camera.cy: 255.313989

Camera.k1: 0.262383
Camera.k2: -0.953104
Camera.p1: -0.005358
Camera.p2: 0.002628
Camera.k3: 1.163314

Camera.width: 640
Camera.height: 480
Camera.fps: 30.0
Camera.bf: 40.0
Camera.RGB: 1
ThDepth: 40.0
DepthMapFactor: 5000.0

ORBextractor.nFeatures: 1000
ORBextractor.scaleFactor: 1.2
ORBextractor.nLevels: 8
ORBextractor.iniThFAST: 20
ORBextractor.minThFAST: 7
Viewer.KeyFrameSize: 0.05
";

/// A rectified stereo file in ORB-SLAM2's EuRoC form (LEFT/RIGHT K, D, R, P matrices).
fn stereo_yaml() -> String {
    let side = |name: &str, tx: f64| {
        format!(
            "{name}.height: 480\n{name}.width: 640\n\
             {name}.D: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data:[-0.28, 0.07, 0.0002, 0.00002, 0.0]\n\
             {name}.K: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [458.654, 0.0, 367.215, 0.0, 457.296, 248.375, 0.0, 0.0, 1.0]\n\
             {name}.R: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n\
             {name}.P: !!opencv-matrix\n   rows: 3\n   cols: 4\n   dt: d\n   data: [435.2, 0, 367.45, {tx}, 0, 435.2, 252.2, 0, 0, 0, 1, 0]\n"
        )
    };
    format!(
        "%YAML:1.0\nCamera.fx: 435.2\nCamera.fy: 435.2\nCamera.cx: 367.45\nCamera.cy: 252.2\n\
         Camera.k1: 0.0\nCamera.k2: 0.0\nCamera.p1: 0.0\nCamera.p2: 0.0\n\
         Camera.width: 640\nCamera.height: 480\nCamera.fps: 20.0\nCamera.bf: 47.9\nCamera.RGB: 1\n\
         ThDepth: 35\n{}{}",
        side("LEFT", 0.0),
        side("RIGHT", -47.9)
    )
}

/// stillpoint's own TOML form of an RGB-D camera.
fn settings_toml() -> String {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.toml");
    let mut s = stillpoint_datasets::Settings::with_camera(
        Sensor::Rgbd,
        stillpoint_geometry::PinholeCamera::new(535.4, 539.2, 320.1, 247.6, 640, 480),
    );
    s.depth_factor = 5000.0;
    write_settings_toml(&p, &s).unwrap();
    std::fs::read_to_string(p).unwrap()
}

/// A TUM list (`stamp path`) of `n` frames.
fn tum_list(n: usize, folder: &str) -> String {
    let mut s = format!("# {folder} images\n# file: 'x.bag'\n# timestamp filename\n");
    for i in 0..n {
        let t = 1305031102.175304 + i as f64 * 0.033;
        s.push_str(&format!("{t:.6} {folder}/{t:.6}.png\n"));
    }
    s
}

/// Bytes that make readers take other paths than plain text: separators, YAML and TOML syntax,
/// numbers at the edges of their ranges, a byte-order mark, invalid UTF-8.
const TOKENS: &[&str] = &[
    "\n",
    "\r\n",
    " ",
    "\t",
    ":",
    ": ",
    "#",
    "-",
    "[",
    "]",
    "{",
    "}",
    ",",
    "=",
    "\"",
    "'",
    "!!",
    "%YAML:1.0",
    "&a ",
    "*a",
    "<<: ",
    "? ",
    "|",
    ">",
    "\u{feff}",
    "\u{0}",
    "\u{ff}",
    "0",
    "-0",
    "1",
    "-1",
    "0.0",
    "1e-300",
    "1e300",
    "1e309",
    "-1e309",
    "nan",
    "NaN",
    ".nan",
    "inf",
    ".inf",
    "-inf",
    "99999999999999999999",
    "18446744073709551616",
    "0x10",
    "1_000",
    "true",
    "null",
    "~",
    "Camera.fx",
    "Camera1.fx",
    "DepthMapFactor",
    "Camera.bf",
    "Stereo.b",
    "LEFT.P",
    "data:",
    "rows: 3",
    "[camera]",
    "[orb]",
    "fx = ",
    "sensor = \"stereo\"",
    "rgb/1.png",
    "1305031102.1",
];

/// One edit of a file.
#[derive(Clone, Debug)]
enum Edit {
    /// Flip bits of the byte at (position modulo length).
    Flip(usize, u8),
    /// Insert a [`TOKENS`] entry.
    Insert(usize, usize),
    /// Delete up to `n` bytes.
    Delete(usize, usize),
    /// Replace the number at or after the position with a [`TOKENS`] entry.
    Number(usize, usize),
    /// Duplicate a line.
    DupLine(usize),
    /// Swap two lines.
    SwapLines(usize, usize),
    /// Cut the file.
    Truncate(usize),
}

fn edit() -> impl Strategy<Value = Edit> {
    let tok = 0..TOKENS.len();
    prop_oneof![
        (any::<usize>(), 1..=255u8).prop_map(|(p, b)| Edit::Flip(p, b)),
        (any::<usize>(), tok.clone()).prop_map(|(p, t)| Edit::Insert(p, t)),
        (any::<usize>(), 1..40usize).prop_map(|(p, n)| Edit::Delete(p, n)),
        (any::<usize>(), tok.clone()).prop_map(|(p, t)| Edit::Number(p, t)),
        (any::<usize>(), tok).prop_map(|(p, t)| Edit::Number(p, t)),
        any::<usize>().prop_map(Edit::DupLine),
        (any::<usize>(), any::<usize>()).prop_map(|(a, b)| Edit::SwapLines(a, b)),
        any::<usize>().prop_map(Edit::Truncate),
    ]
}

fn apply(mut bytes: Vec<u8>, edits: &[Edit]) -> Vec<u8> {
    for e in edits {
        let len = bytes.len();
        let at = |p: usize| if len == 0 { 0 } else { p % (len + 1) };
        match *e {
            Edit::Flip(p, b) if len > 0 => bytes[p % len] ^= b,
            Edit::Flip(..) => {}
            Edit::Insert(p, t) => {
                let p = at(p);
                bytes.splice(p..p, TOKENS[t].bytes());
            }
            Edit::Delete(p, n) => {
                let p = at(p);
                bytes.drain(p..(p + n).min(len));
            }
            Edit::Number(p, t) => {
                let p = at(p);
                let Some(start) = bytes[p..]
                    .iter()
                    .position(|b| b.is_ascii_digit())
                    .map(|i| p + i)
                else {
                    continue;
                };
                let end = bytes[start..]
                    .iter()
                    .position(|&b| !(b.is_ascii_digit() || b == b'.' || b == b'e' || b == b'-'))
                    .map_or(len, |i| start + i);
                bytes.splice(start..end, TOKENS[t].bytes());
            }
            Edit::DupLine(_) | Edit::SwapLines(..) | Edit::Truncate(_) if len == 0 => {}
            Edit::DupLine(n) => {
                let mut lines: Vec<Vec<u8>> =
                    bytes.split(|&b| b == b'\n').map(<[u8]>::to_vec).collect();
                let l = lines[n % lines.len()].clone();
                lines.insert(n % lines.len(), l);
                bytes = lines.join(&b'\n');
            }
            Edit::SwapLines(a, b) => {
                let mut lines: Vec<Vec<u8>> =
                    bytes.split(|&b| b == b'\n').map(<[u8]>::to_vec).collect();
                let n = lines.len();
                lines.swap(a % n, b % n);
                bytes = lines.join(&b'\n');
            }
            Edit::Truncate(n) => bytes.truncate(n % len),
        }
    }
    bytes
}

/// A settings file's bytes, to be written under `name`, read back by `read_settings`.
fn check_settings(name: &str, bytes: &[u8]) -> Result<(), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    match read_settings(&path) {
        Err(e) => {
            let msg = e.to_string();
            prop_assert!(msg.contains(name), "error without the file name: {msg}");
            prop_assert!(!msg.contains('\n'), "error of more than one line: {msg:?}");
        }
        Ok(s) => {
            // What is accepted is sane, and survives the TOML form.
            let c = &s.camera;
            prop_assert!(
                c.fx >= 1.0 && c.fy >= 1.0 && c.fx <= 1e6 && c.fy <= 1e6,
                "{c:?}"
            );
            prop_assert!(c.width >= 1 && c.height >= 1, "{c:?}");
            prop_assert!(s.fps > 0.0 && s.th_depth > 0.0, "{s:?}");
            prop_assert!(s.orb.n_features > 0 && s.orb.scale_factor > 1.0, "{s:?}");
            if s.sensor == Sensor::Rgbd {
                prop_assert!(s.depth_factor > 0.0, "{s:?}");
            }
            let back = dir.path().join("back.toml");
            write_settings_toml(&back, &s).unwrap();
            prop_assert_eq!(read_settings(&back).unwrap(), s);
        }
    }
    Ok(())
}

/// A list file's bytes, read as a TUM list, an association file and KITTI times.
fn check_lists(bytes: &[u8]) -> Result<(), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rgb.txt");
    std::fs::write(&path, bytes).unwrap();
    let named = |msg: String| -> Result<(), TestCaseError> {
        prop_assert!(
            msg.contains("rgb.txt"),
            "error without the file name: {msg}"
        );
        prop_assert!(!msg.contains('\n'), "error of more than one line: {msg:?}");
        Ok(())
    };
    let increasing = |stamps: &[f64]| stamps.windows(2).all(|w| w[0] < w[1]);
    match read_stamped_list(&path, dir.path()) {
        Err(e) => {
            let msg = e.to_string();
            named(msg.clone())?;
            // A line number after the name: `rgb.txt:3: ...`.
            prop_assert!(msg.contains("rgb.txt:"), "no line in {msg}");
        }
        Ok(list) => {
            prop_assert!(!list.is_empty());
            let stamps: Vec<f64> = list.iter().map(|l| l.0).collect();
            prop_assert!(stamps.iter().all(|t| t.is_finite()) && increasing(&stamps));
            // Relative to the list's folder, or absolute as written.
            prop_assert!(
                list.iter()
                    .all(|l| l.1.starts_with(dir.path()) || l.1.is_absolute())
            );
        }
    }
    match read_associations(&path, dir.path()) {
        Err(e) => named(e.to_string())?,
        Ok(list) => {
            let stamps: Vec<f64> = list.iter().map(|e| e.rgb_stamp).collect();
            prop_assert!(!list.is_empty() && increasing(&stamps));
            prop_assert!(list.iter().all(|e| e.depth_stamp.is_finite()));
        }
    }
    match read_times(&path) {
        Err(e) => named(e.to_string())?,
        Ok(t) => prop_assert!(t.iter().all(|t| t.is_finite()) && increasing(&t)),
    }
    Ok(())
}

/// A TUM folder with these `rgb.txt` and `depth.txt` (no images), opened whole: the lists are
/// read and associated; the first frame's images are missing, which the run would skip.
fn check_tum_folder(rgb: &[u8], depth: &[u8]) -> Result<(), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("rgb.txt"), rgb).unwrap();
    std::fs::write(dir.path().join("depth.txt"), depth).unwrap();
    match open(dir.path(), Some(DatasetKind::Tum), None) {
        Err(e) => {
            let msg = e.to_string();
            prop_assert!(
                msg.contains("rgb.txt") || msg.contains("depth.txt") || msg.contains("depth frame"),
                "error naming no file: {msg}"
            );
        }
        Ok(seq) => {
            prop_assert!(!seq.is_empty());
            let stamps: Vec<f64> = (0..seq.len()).map(|i| seq.timestamp(i).unwrap()).collect();
            prop_assert!(stamps.windows(2).all(|w| w[0] < w[1]), "{stamps:?}");
            prop_assert!(seq.frame(0).is_err(), "frame 0 has no images");
        }
    }
    Ok(())
}

/// TUM's association rule on any stamps: one-to-one, within the tolerance, sorted by rgb.
fn check_association(a: &[f64], b: &[f64], max_diff: f64) -> Result<(), TestCaseError> {
    let pairs = associate_nearest(a, b, max_diff);
    let (mut used_a, mut used_b) = (vec![false; a.len()], vec![false; b.len()]);
    for &(i, j) in &pairs {
        prop_assert!(i < a.len() && j < b.len());
        prop_assert!(!used_a[i] && !used_b[j], "not one-to-one: {pairs:?}");
        used_a[i] = true;
        used_b[j] = true;
        prop_assert!((a[i] - b[j]).abs() < max_diff);
    }
    prop_assert!(pairs.windows(2).all(|w| w[0].0 < w[1].0));
    Ok(())
}

/// Sorted stamps with gaps of 0 to 0.05 s (TUM lists at 30 Hz, with drops and repeats).
fn stamps() -> impl Strategy<Value = Vec<f64>> {
    (0.0..2e9f64, proptest::collection::vec(0.0..0.05f64, 0..60)).prop_map(|(t0, gaps)| {
        gaps.iter()
            .scan(t0, |t, g| {
                *t += g;
                Some(*t)
            })
            .collect()
    })
}

/// Lines of numbers, names and junk.
fn numberish() -> impl Strategy<Value = Vec<u8>> {
    let field = prop_oneof![
        any::<f64>().prop_map(|v| v.to_string()),
        (1.3e9..1.4e9f64).prop_map(|v| format!("{v:.6}")),
        (0..TOKENS.len()).prop_map(|t| TOKENS[t].to_string()),
        "[a-z/._]{0,12}",
    ];
    proptest::collection::vec(proptest::collection::vec(field, 0..6), 0..20).prop_map(|lines| {
        lines
            .iter()
            .map(|l| l.join(" ") + "\n")
            .collect::<String>()
            .into_bytes()
    })
}

fn random_bytes() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(any::<u8>(), 0..600)
}

fn edits() -> impl Strategy<Value = Vec<Edit>> {
    proptest::collection::vec(edit(), 1..8)
}

/// Which valid settings file a mutation starts from.
fn settings_base(which: u8) -> (&'static str, Vec<u8>) {
    match which % 3 {
        0 => ("TUM1.yaml", TUM1_YAML.as_bytes().to_vec()),
        1 => ("EuRoC.yaml", stereo_yaml().into_bytes()),
        _ => ("settings.toml", settings_toml().into_bytes()),
    }
}

/// Run `check` on `cases` values of `strategy`; fail with the smallest failing value. Prints the
/// case count and time (seen with `--nocapture`).
fn fuzz<S: Strategy>(
    name: &str,
    cases: u32,
    strategy: S,
    check: impl Fn(S::Value) -> Result<(), TestCaseError>,
) where
    S::Value: std::fmt::Debug,
{
    let started = std::time::Instant::now();
    let result = proptest::test_runner::TestRunner::new(config(cases)).run(&strategy, check);
    eprintln!("{name}: {cases} cases in {:.0?}", started.elapsed());
    if let Err(e) = result {
        panic!("{name}: {e}");
    }
}

fn settings_random_bytes(cases: u32) {
    fuzz(
        "settings, random bytes",
        cases,
        (random_bytes(), any::<bool>()),
        |(bytes, toml)| check_settings(if toml { "r.toml" } else { "r.yaml" }, &bytes),
    );
}

fn settings_mutated(cases: u32) {
    fuzz(
        "settings, mutated",
        cases,
        (any::<u8>(), edits()),
        |(which, edits)| {
            let (name, base) = settings_base(which);
            check_settings(name, &apply(base, &edits))
        },
    );
}

fn lists_random(cases: u32) {
    fuzz(
        "lists, random bytes or numberish lines",
        cases,
        prop_oneof![random_bytes(), numberish()],
        |bytes| check_lists(&bytes),
    );
}

fn lists_mutated(cases: u32) {
    fuzz(
        "lists, mutated",
        cases,
        (0..12usize, edits()),
        |(n, edits)| check_lists(&apply(tum_list(n, "rgb").into_bytes(), &edits)),
    );
}

fn tum_folder_mutated(cases: u32) {
    fuzz(
        "TUM folder, mutated lists",
        cases,
        (0..12usize, 0..12usize, edits(), edits()),
        |(n, m, e1, e2)| {
            let rgb = apply(tum_list(n, "rgb").into_bytes(), &e1);
            let depth = apply(tum_list(m, "depth").into_bytes(), &e2);
            check_tum_folder(&rgb, &depth)
        },
    );
}

fn association(cases: u32) {
    fuzz(
        "association rule",
        cases,
        (
            stamps(),
            stamps(),
            prop_oneof![Just(0.02), 0.0..0.1f64],
            proptest::collection::vec(any::<f64>(), 0..8),
        ),
        |(a, b, max_diff, junk)| {
            check_association(&a, &b, max_diff)?;
            // Unsorted, NaN or infinite stamps: no panic.
            let _ = associate_nearest(&junk, &a, max_diff);
            let _ = associate_nearest(&a, &junk, f64::NAN);
            Ok(())
        },
    );
}

#[test]
fn fuzz_settings_random_bytes() {
    settings_random_bytes(256);
}

#[test]
fn fuzz_settings_mutated() {
    settings_mutated(256);
}

#[test]
fn fuzz_lists_random() {
    lists_random(256);
}

#[test]
fn fuzz_lists_mutated() {
    lists_mutated(256);
}

#[test]
fn fuzz_tum_folder_mutated() {
    tum_folder_mutated(256);
}

#[test]
fn fuzz_association() {
    association(256);
}

#[test]
#[ignore = "long fuzz run: STILLPOINT_FUZZ_CASES cases"]
fn long_fuzz_settings() {
    settings_random_bytes(long_cases());
    settings_mutated(long_cases());
}

#[test]
#[ignore = "long fuzz run: STILLPOINT_FUZZ_CASES cases"]
fn long_fuzz_lists() {
    lists_random(long_cases());
    lists_mutated(long_cases());
    tum_folder_mutated(long_cases());
    association(long_cases());
}

/// The valid bases are read as they are (the mutations start from files that work).
#[test]
fn the_unmutated_bases_are_read() {
    for which in 0..3 {
        let (name, bytes) = settings_base(which);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        read_settings(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("rgb.txt");
    std::fs::write(&p, tum_list(5, "rgb")).unwrap();
    assert_eq!(read_stamped_list(&p, dir.path()).unwrap().len(), 5);
}
