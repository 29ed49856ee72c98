//! The [`Sequence`] trait, the dataset kinds, and [`open`] with layout auto-detection.

use crate::error::{DatasetError, layout_err};
use crate::{Frame, Settings};
use std::path::{Path, PathBuf};

/// A sequence of frames read lazily by index: nothing but file lists is held in memory.
pub trait Sequence: Send {
    /// Camera and front-end settings for every frame.
    fn settings(&self) -> &Settings;
    /// Number of frames.
    fn len(&self) -> usize;
    /// True when there is no frame.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Load frame `i` from disk.
    fn frame(&self, i: usize) -> Result<Frame, DatasetError>;
    /// Ground-truth trajectory file, when the sequence has one (format: [`Self::ground_truth_format`]).
    fn ground_truth(&self) -> Option<PathBuf>;
    /// How [`Self::ground_truth`] is written.
    fn ground_truth_format(&self) -> GroundTruthFormat {
        GroundTruthFormat::Tum
    }
    /// `boxes.jsonl` of per-frame object boxes, when present.
    fn boxes(&self) -> Option<PathBuf>;
    /// A short name (the directory name).
    fn name(&self) -> String;
    /// Stamp of frame `i` without loading it.
    fn timestamp(&self, i: usize) -> Option<f64>;
}

/// The formats of ground-truth files.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GroundTruthFormat {
    /// `timestamp tx ty tz qx qy qz qw` (TUM, Bonn, synth).
    Tum,
    /// KITTI `poses/NN.txt`: a row-major 3x4 `[R | t]` per frame, no stamps (line i is frame i).
    KittiPoses,
    /// EuRoC `state_groundtruth_estimate0/data.csv` (nanosecond stamps, body frame).
    EurocCsv,
}

/// The layouts [`open`] reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DatasetKind {
    /// TUM RGB-D or Bonn RGB-D Dynamic (`rgb.txt`, `depth.txt`, `groundtruth.txt`).
    Tum,
    /// stillpoint's synthetic sequences: the TUM layout plus `boxes.jsonl` and `settings.toml`.
    Synth,
    /// KITTI odometry (`image_0/1` or `image_2/3`, `calib.txt`, `times.txt`).
    Kitti,
    /// EuRoC MAV (`mav0/cam0/data.csv`, `sensor.yaml`).
    Euroc,
    /// A folder of images, monocular, at the settings' frame rate.
    Folder,
}

impl std::str::FromStr for DatasetKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "tum" | "bonn" => Ok(Self::Tum),
            "synth" => Ok(Self::Synth),
            "kitti" => Ok(Self::Kitti),
            "euroc" => Ok(Self::Euroc),
            "folder" | "images" => Ok(Self::Folder),
            o => Err(format!(
                "unknown dataset kind {o:?} (tum, bonn, synth, kitti, euroc, folder)"
            )),
        }
    }
}

pub(crate) fn is_image(p: &Path) -> bool {
    p.extension().is_some_and(|e| {
        let e = e.to_ascii_lowercase();
        e == "png" || e == "jpg" || e == "jpeg"
    })
}

/// Which layout `dir` has.
pub fn detect_kind(dir: &Path) -> Result<DatasetKind, DatasetError> {
    if !dir.is_dir() {
        if dir.extension().is_some_and(|e| e == "mcap" || e == "bag") {
            return Err(layout_err(
                dir,
                "a ROS recording, not a sequence folder: give it as --bag FILE --rgb-topic TOPIC",
            ));
        }
        if dir.extension().is_some_and(|e| {
            let e = e.to_ascii_lowercase();
            ["mp4", "mov", "m4v", "mkv", "avi", "webm"]
                .iter()
                .any(|v| e == *v)
        }) {
            return Err(layout_err(
                dir,
                "a video file, not a sequence folder: give it as --video FILE",
            ));
        }
        return Err(layout_err(dir, "not a directory"));
    }
    if dir.join("mav0").is_dir() || dir.join("cam0/data.csv").is_file() {
        return Ok(DatasetKind::Euroc);
    }
    // Before KITTI: `stillpoint synth --stereo` writes the TUM layout and the KITTI one in the
    // same folder; RGB-D is its main reading (`--kind kitti` picks the stereo one).
    if dir.join("rgb.txt").is_file() {
        return Ok(if dir.join("boxes.jsonl").is_file() {
            DatasetKind::Synth
        } else {
            DatasetKind::Tum
        });
    }
    if dir.join("image_0").is_dir() || dir.join("image_2").is_dir() {
        return Ok(DatasetKind::Kitti);
    }
    let has_images = std::fs::read_dir(dir)
        .map_err(crate::error::io_err(dir))?
        .filter_map(Result::ok)
        .any(|e| is_image(&e.path()));
    if has_images {
        return Ok(DatasetKind::Folder);
    }
    Err(layout_err(
        dir,
        "no known dataset layout (rgb.txt, image_0/, mav0/, or image files)",
    ))
}

/// Open a sequence. `kind` None detects the layout; `settings` is a settings file (ORB-SLAM
/// `%YAML:1.0` or our `.toml`) overriding what the sequence carries.
///
/// ```no_run
/// let seq = stillpoint_datasets::open("data/rgbd_dataset_freiburg3_walking_xyz".as_ref(), None, None)?;
/// let first = seq.frame(0)?;
/// println!("{} frames, first at {}", seq.len(), first.timestamp);
/// # Ok::<(), stillpoint_datasets::DatasetError>(())
/// ```
pub fn open(
    dir: &Path,
    kind: Option<DatasetKind>,
    settings: Option<&Path>,
) -> Result<Box<dyn Sequence>, DatasetError> {
    let kind = match kind {
        Some(k) => k,
        None => detect_kind(dir)?,
    };
    let settings = settings.map(crate::read_settings).transpose()?;
    let seq: Box<dyn Sequence> = match kind {
        DatasetKind::Tum | DatasetKind::Synth => {
            Box::new(crate::tum::TumSequence::open(dir, settings)?)
        }
        DatasetKind::Kitti => Box::new(crate::kitti::KittiSequence::open(dir, settings)?),
        DatasetKind::Euroc => Box::new(crate::euroc::EurocSequence::open(dir, settings)?),
        DatasetKind::Folder => Box::new(crate::folder::FolderSequence::open(dir, settings)?),
    };
    // Images of another size than the camera are a wrong settings file, not a bad frame: say
    // so now rather than skipping every frame. (Other faults of frame 0 are left to the run,
    // which skips bad frames.)
    if !seq.is_empty()
        && let Err(e @ DatasetError::SizeMismatch { .. }) = seq.frame(0)
    {
        return Err(e);
    }
    Ok(seq)
}

pub(crate) fn dir_name(dir: &Path) -> String {
    dir.canonicalize()
        .ok()
        .and_then(|d| d.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| dir.display().to_string())
}

pub(crate) fn check_index(i: usize, len: usize) -> Result<(), DatasetError> {
    if i < len {
        Ok(())
    } else {
        Err(DatasetError::OutOfRange { index: i, len })
    }
}

/// An image whose size differs from the camera's is an error naming the file.
/// An image's size from its file header, without decoding the pixels; `None` when the header
/// cannot be read (the decoder then says why).
pub(crate) fn header_size(path: &Path) -> Option<(usize, usize)> {
    stillpoint_image::codec::file_dimensions(path).ok()?
}

/// [`check_size`] from the file's header, before the image is decoded: a small file can declare
/// a huge image (a 445 KB PNG of 12000x12000 took 850 MB to decode, only to be told it was the
/// wrong size).
pub(crate) fn check_header(path: &Path, s: &Settings) -> Result<(), DatasetError> {
    match header_size(path) {
        Some((w, h)) => check_size(path, w, h, s),
        None => Ok(()),
    }
}

pub(crate) fn check_size(
    path: &Path,
    w: usize,
    h: usize,
    s: &Settings,
) -> Result<(), DatasetError> {
    if w == s.camera.width as usize && h == s.camera.height as usize {
        Ok(())
    } else {
        Err(DatasetError::SizeMismatch {
            path: path.display().to_string(),
            width: w,
            height: h,
            expected_width: s.camera.width,
            expected_height: s.camera.height,
        })
    }
}
