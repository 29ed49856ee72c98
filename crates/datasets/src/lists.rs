//! Small text files of sequences: TUM lists (`stamp path`), association files
//! (`stamp path stamp path`), KITTI `times.txt`, and the TUM association rule.

use crate::error::{DatasetError, io_err, parse_err};
use std::path::{Path, PathBuf};

/// Data lines of a text file: (1-based line number, trimmed text); `#` comments and blank lines
/// skipped.
pub(crate) fn data_lines(path: &Path) -> Result<Vec<(usize, String)>, DatasetError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    // Windows editors start UTF-8 files with a byte-order mark; it is not part of the first line.
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&bytes);
    let mut out = Vec::new();
    for (i, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let text = std::str::from_utf8(raw)
            .map_err(|_| parse_err(path, i + 1, "line is not valid UTF-8 text"))?
            .trim();
        if !text.is_empty() && !text.starts_with('#') {
            out.push((i + 1, text.to_string()));
        }
    }
    Ok(out)
}

pub(crate) fn parse_stamp(path: &Path, line: usize, field: &str) -> Result<f64, DatasetError> {
    match field.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(parse_err(
            path,
            line,
            format!("timestamp {field:?} is not finite"),
        )),
        Err(_) => Err(parse_err(
            path,
            line,
            format!("{field:?} is not a timestamp"),
        )),
    }
}

/// Check that stamps increase strictly; the error names the offending line.
fn check_sorted(path: &Path, items: &[(usize, f64)]) -> Result<(), DatasetError> {
    for w in items.windows(2) {
        if w[1].1 == w[0].1 {
            return Err(parse_err(
                path,
                w[1].0,
                format!("duplicate timestamp {}", w[1].1),
            ));
        }
        if w[1].1 < w[0].1 {
            return Err(parse_err(
                path,
                w[1].0,
                format!(
                    "timestamp {} is before the previous one ({}); stamps must be sorted",
                    w[1].1, w[0].1
                ),
            ));
        }
    }
    Ok(())
}

/// A timestamped file list (TUM `rgb.txt` / `depth.txt`): `stamp relative/path` per line, paths
/// resolved against `base`. Stamps must increase strictly.
pub fn read_stamped_list(path: &Path, base: &Path) -> Result<Vec<(f64, PathBuf)>, DatasetError> {
    let mut out = Vec::new();
    let mut lines = Vec::new();
    for (line, text) in data_lines(path)? {
        let mut f = text.split_whitespace();
        let (Some(s), Some(file), None) = (f.next(), f.next(), f.next()) else {
            return Err(parse_err(path, line, "expected \"timestamp filename\""));
        };
        let t = parse_stamp(path, line, s)?;
        lines.push((line, t));
        out.push((t, base.join(file)));
    }
    check_sorted(path, &lines)?;
    if out.is_empty() {
        return Err(parse_err(path, 1, "no entries in file"));
    }
    Ok(out)
}

/// One associated RGB-D frame.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbdEntry {
    /// Colour image time, seconds.
    pub rgb_stamp: f64,
    /// Colour image file.
    pub rgb: PathBuf,
    /// Depth image time, seconds.
    pub depth_stamp: f64,
    /// Depth image file.
    pub depth: PathBuf,
}

/// An association file (`rgb_stamp rgb_path depth_stamp depth_path`, as TUM's associate.py
/// writes it; ORB-SLAM, DynaSLAM and Crowd-SLAM ship them). RGB stamps must increase strictly.
pub fn read_associations(path: &Path, base: &Path) -> Result<Vec<RgbdEntry>, DatasetError> {
    let mut out = Vec::new();
    let mut lines = Vec::new();
    for (line, text) in data_lines(path)? {
        let f: Vec<&str> = text.split_whitespace().collect();
        if f.len() != 4 {
            return Err(parse_err(
                path,
                line,
                format!(
                    "expected 4 fields (rgb_stamp rgb depth_stamp depth), found {}",
                    f.len()
                ),
            ));
        }
        let rgb_stamp = parse_stamp(path, line, f[0])?;
        let depth_stamp = parse_stamp(path, line, f[2])?;
        lines.push((line, rgb_stamp));
        out.push(RgbdEntry {
            rgb_stamp,
            rgb: base.join(f[1]),
            depth_stamp,
            depth: base.join(f[3]),
        });
    }
    check_sorted(path, &lines)?;
    if out.is_empty() {
        return Err(parse_err(path, 1, "no entries in file"));
    }
    Ok(out)
}

/// TUM's association rule (`associate.py`): every (rgb, depth) pair closer than `max_diff`
/// seconds is a candidate; candidates are taken by increasing time difference, each stamp used at
/// most once (one-to-one). Returns (rgb index, depth index) sorted by rgb index. Both inputs must
/// be sorted.
///
/// ```
/// let pairs = stillpoint_datasets::associate_nearest(&[1.0, 1.1, 1.2], &[1.005, 1.19], 0.02);
/// assert_eq!(pairs, vec![(0, 0), (2, 1)]);
/// ```
pub fn associate_nearest(a: &[f64], b: &[f64], max_diff: f64) -> Vec<(usize, usize)> {
    let mut candidates = Vec::new();
    for (i, &t) in a.iter().enumerate() {
        let start = b.partition_point(|&x| x < t - max_diff);
        for (j, &u) in b.iter().enumerate().skip(start) {
            if u > t + max_diff {
                break;
            }
            let d = (t - u).abs();
            if d < max_diff {
                candidates.push((d, i, j));
            }
        }
    }
    candidates.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    let (mut used_a, mut used_b) = (vec![false; a.len()], vec![false; b.len()]);
    let mut out = Vec::new();
    for (_, i, j) in candidates {
        if !used_a[i] && !used_b[j] {
            used_a[i] = true;
            used_b[j] = true;
            out.push((i, j));
        }
    }
    out.sort_unstable();
    out
}

/// KITTI `times.txt`: one stamp in seconds per line, strictly increasing.
pub fn read_times(path: &Path) -> Result<Vec<f64>, DatasetError> {
    let mut lines = Vec::new();
    for (line, text) in data_lines(path)? {
        lines.push((line, parse_stamp(path, line, &text)?));
    }
    check_sorted(path, &lines)?;
    Ok(lines.into_iter().map(|l| l.1).collect())
}
