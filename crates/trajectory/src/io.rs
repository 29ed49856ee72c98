//! Reading and writing trajectories: TUM (`timestamp tx ty tz qx qy qz qw`), KITTI (a row-major
//! 3x4 `[R | t]` per line, 12 numbers) and EuRoC ground-truth csv (`timestamp_ns, px, py, pz, qw,
//! qx, qy, qz, ...`).
//!
//! Parsers take bytes and a name for messages, so they can be fed anything: every malformed input
//! is an error naming the file and line, never a panic.

use crate::Trajectory;
use crate::error::{TrajectoryError, io_err};
use std::io::Write;
use std::path::Path;
use stillpoint_geometry::{Se3, se3_from_3x4, se3_from_tum, se3_to_3x4, se3_to_tum};

/// The trajectory file formats stillpoint reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrajectoryFormat {
    /// `timestamp tx ty tz qx qy qz qw`, `#` comments.
    Tum,
    /// 12 numbers a line (row-major `[R | t]`), no timestamps: the line index is the stamp.
    Kitti,
    /// EuRoC ground-truth csv: nanosecond stamp, position, quaternion w x y z, more columns ignored.
    Euroc,
}

impl std::str::FromStr for TrajectoryFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "tum" => Ok(Self::Tum),
            "kitti" => Ok(Self::Kitti),
            "euroc" => Ok(Self::Euroc),
            other => Err(format!(
                "unknown trajectory format {other:?} (tum, kitti, euroc)"
            )),
        }
    }
}

/// Read a trajectory file in the given format. Strict: equal (duplicate) timestamps are an error
/// naming the line. See [`read_trajectory_lenient`] for real files that contain them.
pub fn read_trajectory(
    path: &Path,
    format: TrajectoryFormat,
) -> Result<Trajectory, TrajectoryError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&bytes);
    parse(bytes, &path.display().to_string(), format, false).map(|(t, _)| t)
}

/// Read a trajectory file, keeping poses with a timestamp equal to the previous one, as evo does
/// (TUM's fr2/desk ground truth and evo's EuRoC V1_02 estimate contain such lines). Returns the
/// trajectory and the line numbers of the duplicates, so the caller can log them. Decreasing
/// timestamps are still an error.
pub fn read_trajectory_lenient(
    path: &Path,
    format: TrajectoryFormat,
) -> Result<(Trajectory, Vec<usize>), TrajectoryError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&bytes);
    parse(bytes, &path.display().to_string(), format, true)
}

/// Parse text in the given format; with `allow_duplicates`, equal stamps are kept and their lines
/// returned.
pub fn parse(
    bytes: &[u8],
    name: &str,
    format: TrajectoryFormat,
    allow_duplicates: bool,
) -> Result<(Trajectory, Vec<usize>), TrajectoryError> {
    let mut dups = Vec::new();
    let dup_sink = if allow_duplicates {
        Some(&mut dups)
    } else {
        None
    };
    let traj = match format {
        TrajectoryFormat::Tum => parse_tum_impl(bytes, name, dup_sink),
        TrajectoryFormat::Kitti => parse_kitti_impl(bytes, name),
        TrajectoryFormat::Euroc => parse_euroc_impl(bytes, name, dup_sink),
    }?;
    Ok((traj, dups))
}

/// Read a TUM trajectory file.
///
/// ```no_run
/// let traj = stillpoint_trajectory::read_tum(std::path::Path::new("groundtruth.txt"))?;
/// println!("{} poses", traj.len());
/// # Ok::<(), stillpoint_trajectory::TrajectoryError>(())
/// ```
pub fn read_tum(path: &Path) -> Result<Trajectory, TrajectoryError> {
    read_trajectory(path, TrajectoryFormat::Tum)
}

/// Read a KITTI poses file; stamps are the line indices 0, 1, 2, ...
pub fn read_kitti(path: &Path) -> Result<Trajectory, TrajectoryError> {
    read_trajectory(path, TrajectoryFormat::Kitti)
}

/// Read an EuRoC ground-truth csv; stamps are converted from nanoseconds to seconds.
pub fn read_euroc(path: &Path) -> Result<Trajectory, TrajectoryError> {
    read_trajectory(path, TrajectoryFormat::Euroc)
}

/// Split into (1-based line number, text) of lines that carry data: blank lines and `#`
/// comments are skipped. Invalid UTF-8 is an error naming the line.
fn data_lines<'a>(
    bytes: &'a [u8],
    name: &'a str,
) -> impl Iterator<Item = Result<(usize, &'a str), TrajectoryError>> + 'a {
    bytes
        .split(|&b| b == b'\n')
        .enumerate()
        .filter_map(move |(i, raw)| match std::str::from_utf8(raw) {
            Err(_) => Some(Err(parse_err(name, i + 1, "line is not valid UTF-8 text"))),
            Ok(s) => {
                let t = s.trim();
                if t.is_empty() || t.starts_with('#') {
                    None
                } else {
                    Some(Ok((i + 1, t)))
                }
            }
        })
}

fn parse_err(name: &str, line: usize, msg: impl Into<String>) -> TrajectoryError {
    TrajectoryError::Parse {
        path: name.to_string(),
        line,
        msg: msg.into(),
    }
}

/// Parse every field as a finite f64.
fn numbers<'a>(
    fields: impl Iterator<Item = &'a str>,
    name: &str,
    line: usize,
) -> Result<Vec<f64>, TrajectoryError> {
    fields
        .map(|f| {
            let v: f64 = f
                .parse()
                .map_err(|_| parse_err(name, line, format!("{f:?} is not a number")))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(parse_err(
                    name,
                    line,
                    format!("{f:?} is not a finite number"),
                ))
            }
        })
        .collect()
}

/// Append a pose, checking that stamps increase strictly.
fn push_pose(
    traj: &mut Trajectory,
    stamp: f64,
    pose: Se3,
    name: &str,
    line: usize,
    dups: &mut Option<&mut Vec<usize>>,
) -> Result<(), TrajectoryError> {
    if let Some(&prev) = traj.stamps.last() {
        if stamp == prev {
            if let Some(d) = dups {
                d.push(line);
                traj.stamps.push(stamp);
                traj.poses.push(pose);
                return Ok(());
            }
            return Err(parse_err(
                name,
                line,
                format!("duplicate timestamp {stamp}"),
            ));
        }
        if stamp < prev {
            return Err(parse_err(
                name,
                line,
                format!(
                    "timestamp {stamp} is before the previous one ({prev}); stamps must be sorted"
                ),
            ));
        }
    }
    traj.stamps.push(stamp);
    traj.poses.push(pose);
    Ok(())
}

/// Parse TUM text (`timestamp tx ty tz qx qy qz qw` per line, `#` comments, blank lines);
/// strict about duplicate stamps.
pub fn parse_tum(bytes: &[u8], name: &str) -> Result<Trajectory, TrajectoryError> {
    parse_tum_impl(bytes, name, None)
}

fn parse_tum_impl(
    bytes: &[u8],
    name: &str,
    mut dups: Option<&mut Vec<usize>>,
) -> Result<Trajectory, TrajectoryError> {
    let mut traj = Trajectory::default();
    for item in data_lines(bytes, name) {
        let (line, text) = item?;
        let v = numbers(text.split_whitespace(), name, line)?;
        if v.len() != 8 {
            return Err(parse_err(
                name,
                line,
                format!(
                    "expected 8 numbers (timestamp tx ty tz qx qy qz qw), found {}",
                    v.len()
                ),
            ));
        }
        let pose = se3_from_tum([v[1], v[2], v[3]], [v[4], v[5], v[6], v[7]])
            .ok_or_else(|| parse_err(name, line, "quaternion has zero length"))?;
        push_pose(&mut traj, v[0], pose, name, line, &mut dups)?;
    }
    if traj.is_empty() {
        return Err(TrajectoryError::Empty { path: name.into() });
    }
    Ok(traj)
}

/// Largest deviation from orthonormality accepted in a KITTI rotation block. KITTI's files carry
/// 7 significant digits; anything much worse is not a rotation.
const KITTI_ROTATION_TOLERANCE: f64 = 1e-2;

/// Parse KITTI poses text (12 numbers a line). Stamps are the pose indices.
pub fn parse_kitti(bytes: &[u8], name: &str) -> Result<Trajectory, TrajectoryError> {
    parse_kitti_impl(bytes, name)
}

fn parse_kitti_impl(bytes: &[u8], name: &str) -> Result<Trajectory, TrajectoryError> {
    let mut traj = Trajectory::default();
    for item in data_lines(bytes, name) {
        let (line, text) = item?;
        let v = numbers(text.split_whitespace(), name, line)?;
        let m: [f64; 12] = v.as_slice().try_into().map_err(|_| {
            parse_err(
                name,
                line,
                format!(
                    "expected 12 numbers (a 3x4 [R|t] matrix), found {}",
                    v.len()
                ),
            )
        })?;
        let r = nalgebra::Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
        let off = (r.transpose() * r - nalgebra::Matrix3::identity()).amax();
        if off.is_nan() || off >= KITTI_ROTATION_TOLERANCE || r.determinant() <= 0.0 {
            return Err(parse_err(
                name,
                line,
                "the 3x3 block is not a rotation matrix",
            ));
        }
        let stamp = traj.len() as f64;
        push_pose(&mut traj, stamp, se3_from_3x4(&m), name, line, &mut None)?;
    }
    if traj.is_empty() {
        return Err(TrajectoryError::Empty { path: name.into() });
    }
    Ok(traj)
}

/// Parse EuRoC csv text: `timestamp[ns], px, py, pz, qw, qx, qy, qz, ...` (header lines start
/// with `#`); strict about duplicate stamps.
pub fn parse_euroc(bytes: &[u8], name: &str) -> Result<Trajectory, TrajectoryError> {
    parse_euroc_impl(bytes, name, None)
}

fn parse_euroc_impl(
    bytes: &[u8],
    name: &str,
    mut dups: Option<&mut Vec<usize>>,
) -> Result<Trajectory, TrajectoryError> {
    let mut traj = Trajectory::default();
    for item in data_lines(bytes, name) {
        let (line, text) = item?;
        let v = numbers(text.split(',').map(str::trim), name, line)?;
        if v.len() < 8 {
            return Err(parse_err(
                name,
                line,
                format!(
                    "expected at least 8 comma-separated numbers (ns, p xyz, q wxyz), found {}",
                    v.len()
                ),
            ));
        }
        let pose = se3_from_tum([v[1], v[2], v[3]], [v[5], v[6], v[7], v[4]])
            .ok_or_else(|| parse_err(name, line, "quaternion has zero length"))?;
        // Same arithmetic as evo: parse as a double, then divide.
        push_pose(&mut traj, v[0] / 1e9, pose, name, line, &mut dups)?;
    }
    if traj.is_empty() {
        return Err(TrajectoryError::Empty { path: name.into() });
    }
    Ok(traj)
}

/// One TUM line. Numbers use Rust's shortest round-trip form, so reading back is exact.
fn tum_line(t: f64, pose: &Se3) -> String {
    let (p, q) = se3_to_tum(pose);
    format!(
        "{t} {} {} {} {} {} {} {}\n",
        p[0], p[1], p[2], q[0], q[1], q[2], q[3]
    )
}

/// Write `text` to a sibling temporary file, then rename it over `path`: a file already there
/// (say, the trajectory written frame by frame before a loop correction rewrote it) is
/// replaced whole or left as it was, never cut short.
fn write_replacing(path: &Path, text: &str) -> Result<(), TrajectoryError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".partial");
    let tmp = std::path::PathBuf::from(tmp);
    if std::fs::write(&tmp, text)
        .and_then(|()| std::fs::rename(&tmp, path))
        .is_ok()
    {
        return Ok(());
    }
    // A folder we may not create files in (e.g. `/dev/stdout`): write in place.
    let _ = std::fs::remove_file(&tmp);
    std::fs::write(path, text).map_err(io_err(path))
}

/// Write a whole trajectory in TUM format.
pub fn write_tum(path: &Path, traj: &Trajectory) -> Result<(), TrajectoryError> {
    let mut s = String::from("# timestamp tx ty tz qx qy qz qw\n");
    for (t, p) in traj.stamps.iter().zip(&traj.poses) {
        s.push_str(&tum_line(*t, p));
    }
    write_replacing(path, &s)
}

/// Write a whole trajectory in KITTI format (stamps are dropped).
pub fn write_kitti(path: &Path, traj: &Trajectory) -> Result<(), TrajectoryError> {
    let mut s = String::new();
    for p in &traj.poses {
        let m = se3_to_3x4(p);
        let row: Vec<String> = m.iter().map(|v| format!("{v:e}")).collect();
        s.push_str(&row.join(" "));
        s.push('\n');
    }
    write_replacing(path, &s)
}

/// Writes a TUM trajectory one pose at a time, each line flushed to the file at once, so a run
/// that crashes keeps every pose written before.
///
/// ```
/// # let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("est.txt");
/// let mut w = stillpoint_trajectory::TumWriter::create(&path)?;
/// w.write(1.0, &stillpoint_geometry::Se3::identity())?;
/// assert_eq!(stillpoint_trajectory::read_tum(&path)?.len(), 1);
/// # Ok::<(), stillpoint_trajectory::TrajectoryError>(())
/// ```
pub struct TumWriter {
    file: std::fs::File,
    path: std::path::PathBuf,
    /// Bytes of whole lines written so far.
    len: u64,
}

impl TumWriter {
    /// Create (truncate) the file and write the header comment.
    pub fn create(path: &Path) -> Result<Self, TrajectoryError> {
        let mut file = std::fs::File::create(path).map_err(io_err(path))?;
        const HEADER: &[u8] = b"# timestamp tx ty tz qx qy qz qw\n";
        file.write_all(HEADER).map_err(io_err(path))?;
        Ok(Self {
            file,
            path: path.to_path_buf(),
            len: HEADER.len() as u64,
        })
    }

    /// Append one pose (camera-to-world) and flush it. When the write fails part way (disk
    /// full), the partial line is cut off again: the file holds whole lines only.
    pub fn write(&mut self, t: f64, pose: &Se3) -> Result<(), TrajectoryError> {
        use std::io::{Seek, SeekFrom};
        let line = tum_line(t, pose);
        // One unbuffered write per line: the line is in the file when this returns.
        match self
            .file
            .write_all(line.as_bytes())
            .and_then(|()| self.file.flush())
        {
            Ok(()) => {
                self.len += line.len() as u64;
                Ok(())
            }
            Err(e) => {
                let _ = self.file.set_len(self.len);
                let _ = self.file.seek(SeekFrom::Start(self.len));
                Err(io_err(&self.path)(e))
            }
        }
    }
}
