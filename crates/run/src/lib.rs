//! stillpoint-run: one run of a sequence with its outputs, as `stillpoint run` makes it.
//!
//! [`run_sequence`] takes [`RunOptions`] (a dataset folder or a ROS recording, the detector or
//! none, the settings layers) and does what lies around [`stillpoint_pipeline::Pipeline`]:
//! it opens the sequence, lays the settings files and `section.key=value` overrides over the
//! dataset's settings ([`settings_layers`]), opens the detector and the dynamic front-end,
//! feeds the frames (in order, or replayed at their timestamps as a live camera delivers them,
//! dropping what arrives while busy), writes the trajectory line by line as it goes under an
//! exclusive lock on the file, rewrites it through the refined keyframes at the end with the
//! keyframe trajectory beside it, and returns a [`RunSummary`] (counts, timings, loop closing,
//! real-time latency). Each output is a [`Sink`] that hears every frame and the end;
//! [`run_with`] adds the caller's own (scoring a run against a sequence's truth is one, in
//! `stillpoint-eval`: this crate scores nothing). A stop flag set from another thread or a
//! signal handler ends the run early with its files complete.
//!
//! ```no_run
//! use stillpoint_run::{RunOptions, run_sequence};
//! let options = RunOptions {
//!     detector: Some("gt".into()),
//!     out: Some("trajectory.txt".into()),
//!     ..RunOptions::new("walking_xyz".into())
//! };
//! let summary = run_sequence(&options, &mut |_| {})?;
//! println!("{} of {} frames tracked", summary.tracked, summary.frames);
//! # Ok::<(), stillpoint_run::RunError>(())
//! ```

#![deny(missing_docs)]

mod output;
pub mod overlay;
mod read_ahead;
pub mod record;
mod replay;
mod session;
pub mod settings;
mod sink;

pub use output::{keyframe_path, other_map_path};
pub use replay::RealtimeReport;
pub use session::{Event, run_sequence, run_source, run_with, settings_layers};
pub use settings::{
    Layered, ReadSettings, RealtimeSettings, RecordImage, RecordSettings, Ros2Settings,
    SettingsTree,
};
pub use sink::{Ended, MovingPixels, Sink, Tracked};
pub use stillpoint_pipeline::MapsReport;

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use stillpoint_datasets::mcap::McapTopics;
use stillpoint_datasets::{DatasetError, DatasetKind, Sensor};
use stillpoint_detect::DetectError;
use stillpoint_pipeline::PipelineError;
use stillpoint_pipeline::settings::SettingsError;
use stillpoint_slam::module::loop_closing::LoopStats;
use stillpoint_trajectory::{Trajectory, TrajectoryError};

/// How one run is set up.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Sequence folder (TUM/Bonn layout, a `stillpoint synth` output, ...), or a ROS recording
    /// when [`Overrides::recording`] is given.
    pub dataset: PathBuf,
    /// Dataset kind; detected when `None`.
    pub kind: Option<DatasetKind>,
    /// ORB-SLAM YAML or stillpoint TOML dataset settings; the dataset's own when `None`.
    pub settings: Option<PathBuf>,
    /// Per-frame trajectory (TUM), written as the run goes; the keyframe trajectory goes beside
    /// it ([`keyframe_path`]). `None` writes nothing.
    pub out: Option<PathBuf>,
    /// The front-end's detector (`yolox`, `gt`, `none`); `None` = dynamic front-end off.
    pub detector: Option<String>,
    /// Only the first N frames (`Some(0)` is an error).
    pub frames: Option<usize>,
    /// The paper's culling only (algorithm 3; none of our culling rules).
    pub paper_cull: bool,
    /// YOLOX ONNX file; `None` takes the settings' model or searches the default places.
    pub model: Option<PathBuf>,
    /// Settings changed from their defaults.
    pub overrides: Overrides,
    /// Replay at the frames' timestamps and drop the frames that arrive while busy.
    pub realtime: bool,
    /// A folder for a picture of each frame: keypoints kept and culled, objects moving and
    /// static ([`overlay`]).
    pub overlay: Option<PathBuf>,
    /// A PLY file for the map's points at the end (the sparse map, movers kept out of it).
    pub map_cloud: Option<PathBuf>,
    /// A PLY file for the dense static cloud: keyframe depth fused without the movers' pixels
    /// (RGB-D, or stereo depth matched densely; `[dense]` settings).
    pub dense_cloud: Option<PathBuf>,
    /// An MCAP file of the run for Foxglove: images, keypoints and boxes, poses, the map
    /// ([`record`]; `[record]` settings).
    pub record: Option<PathBuf>,
    /// Set (from another thread or a signal handler) to stop taking frames; the map and the
    /// files are still finished.
    pub stop: Option<&'static AtomicBool>,
    /// Start in the map saved in this file ([`stillpoint_slam::map_file`]): relocalise in it,
    /// then map on in it (or only localise, `localize`).
    pub load_map: Option<PathBuf>,
    /// With `load_map`: track against the loaded map without changing it.
    pub localize: bool,
    /// Save the final map to this file (written atomically).
    pub save_map: Option<PathBuf>,
}

impl RunOptions {
    /// A run of `dataset` with everything else off or default: no front-end, threaded local
    /// mapping, every frame, no output file.
    pub fn new(dataset: PathBuf) -> Self {
        Self {
            dataset,
            kind: None,
            settings: None,
            out: None,
            detector: None,
            frames: None,
            paper_cull: false,
            model: None,
            overrides: Overrides::default(),
            realtime: false,
            overlay: None,
            map_cloud: None,
            dense_cloud: None,
            record: None,
            stop: None,
            load_map: None,
            localize: false,
            save_map: None,
        }
    }
}

/// What changes besides the dataset and the front-end's mode.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// A stillpoint settings file (`--config`).
    pub config: Option<PathBuf>,
    /// `section.key=value` overrides (`--set`), applied after the file.
    pub sets: Vec<String>,
    /// A DBoW2 text vocabulary instead of the one trained online.
    pub vocabulary: Option<PathBuf>,
    /// `dataset` is a ROS recording read from these topics (`--bag`).
    pub recording: Option<McapTopics>,
    /// `dataset` is a video file (`--video`) or a camera device (`--camera`).
    pub media: Option<Media>,
}

/// Inputs that are neither a dataset folder nor a recording.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Media {
    /// A video file.
    Video,
    /// A live camera.
    Camera,
}

/// What a run produced.
pub struct RunSummary {
    /// The sequence's name.
    pub name: String,
    /// What the SLAM ran on (monocular trajectories have an arbitrary scale).
    pub sensor: Sensor,
    /// Frames asked for (all, or `RunOptions::frames`).
    pub frames: usize,
    /// Frames with a pose.
    pub tracked: usize,
    /// Keyframes in the map at the end.
    pub keyframes: usize,
    /// Map points in the map at the end.
    pub map_points: usize,
    /// Times tracking was lost and came back in the same map.
    pub relocalisations: usize,
    /// Times a new map was started.
    pub new_maps: usize,
    /// The maps made and merged, and frames per map at the end.
    pub maps: MapsReport,
    /// Keypoints the front-end culled, per frame processed.
    pub culled_per_frame: Vec<usize>,
    /// Of those, matched to the map's points and kept by the pose, per frame processed
    /// (monocular frames that offered their culled keypoints to the map,
    /// `front_end.offer_culled_to_map_below`).
    pub culled_matched_per_frame: Vec<usize>,
    /// The per-frame trajectory (frames following their refined keyframes).
    pub trajectory: Trajectory,
    /// The keyframes' poses.
    pub keyframe_trajectory: Trajectory,
    /// stage name -> per-frame (or per-keyframe) times in ms.
    pub timings: Vec<(&'static str, Vec<f64>)>,
    /// Seconds from the first frame read to the outputs written (the detector's model and a
    /// map file are opened before).
    pub wall_s: f64,
    /// What detected: name, backend and input size (`yolox-tract 640x480`), or `off`.
    pub detector: String,
    /// Loop closing's statistics (`None` when it is off).
    pub loops: Option<LoopStats>,
    /// With `realtime`: what the replay at camera rate processed, dropped and how late.
    pub realtime: Option<RealtimeReport>,
    /// Why no frame could be tracked, when none was (features, depth, initialisation).
    pub untracked_reason: Option<String>,
    /// The source ended before its last frame (a cut or corrupt video, a camera gone): why.
    pub ended: Option<String>,
    /// The dense cloud written, when one was asked for.
    pub dense: Option<DenseReport>,
    /// Position in the run of the first frame that relocalised (in a loaded map, the frame
    /// that found its place in it).
    pub first_relocalisation: Option<usize>,
    /// The map loaded and the map saved, when asked for.
    pub map_files: MapFilesReport,
    /// The MCAP recording written, when one was asked for.
    pub record: Option<record::RecordReport>,
}

/// What `load_map` read and `save_map` wrote.
#[derive(Clone, Debug, Default)]
pub struct MapFilesReport {
    /// Keyframes and map points the loaded map held, its file size, and the time to read it
    /// (ms; decoding and checks included).
    pub loaded: Option<MapFileReport>,
    /// The same for the map saved (time: encoding and the atomic write).
    pub saved: Option<MapFileReport>,
}

/// One map file read or written.
#[derive(Clone, Copy, Debug)]
pub struct MapFileReport {
    /// Keyframes in the map (culled ones included).
    pub keyframes: usize,
    /// Map points in the map.
    pub map_points: usize,
    /// File size.
    pub bytes: usize,
    /// Time to read or write it, ms.
    pub ms: f64,
}

/// What `dense_cloud` wrote.
#[derive(Clone, Copy, Debug)]
pub struct DenseReport {
    /// Points (voxels) in the cloud.
    pub points: usize,
    /// Of those, made mostly of pixels the sequence's truth marks as moving (when the run was
    /// given one: [`run_with`]).
    pub on_movers: Option<usize>,
}

impl RunSummary {
    /// mean / median / p90 of the keypoints the front-end culled per frame.
    pub fn culled_stats(&self) -> (f64, f64, f64) {
        count_stats(&self.culled_per_frame)
    }

    /// mean / median / p90 of the culled keypoints matched to map points per frame.
    pub fn culled_matched_stats(&self) -> (f64, f64, f64) {
        count_stats(&self.culled_matched_per_frame)
    }
}

/// mean / median / p90 of per-frame counts.
fn count_stats(counts: &[usize]) -> (f64, f64, f64) {
    let counts: Vec<f64> = counts.iter().map(|&c| c as f64).collect();
    stillpoint_core::stats::stats(&counts)
}

/// Why a run could not start or finish. Each names what it was doing; the cause is its source.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The sequence or recording cannot be opened.
    #[error("opening {}", .path.display())]
    Open {
        /// The dataset folder or recording.
        path: PathBuf,
        /// What the reader said.
        source: DatasetError,
    },
    /// A settings file or override is wrong.
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// A file cannot be opened, locked or created.
    #[error("{context}")]
    Io {
        /// What was being done (`opening FILE`).
        context: String,
        /// Why it failed.
        source: std::io::Error,
    },
    /// The vocabulary file is not a DBoW2 text vocabulary.
    #[error("{}: {msg}", .path.display())]
    Vocabulary {
        /// The file.
        path: PathBuf,
        /// What the reader said.
        msg: String,
    },
    /// The detector cannot be opened or started.
    #[error("{context}")]
    Detector {
        /// What was being done.
        context: String,
        /// What the detector said.
        source: DetectError,
    },
    /// Nothing to run: no frames, or another run writes the same trajectory.
    #[error("{0}")]
    Refused(String),
    /// Writing the trajectory failed.
    #[error("{context}")]
    Trajectory {
        /// What was being written.
        context: String,
        /// Why it failed.
        source: TrajectoryError,
    },
    /// A map file cannot be read, is corrupted, or does not fit the run (camera, sensor,
    /// vocabulary, format version).
    #[error("{}", .path.display())]
    MapFile {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        source: stillpoint_slam::map_file::MapFileError,
    },
    /// Tracking or stopping the pipeline failed.
    #[error("{context}")]
    Pipeline {
        /// The dataset, or what was being stopped.
        context: String,
        /// What the pipeline said.
        source: PipelineError,
    },
}

/// An error and its causes, `: `-separated (as anyhow's `{:#}`): how a failed run is logged or
/// recorded in a table row.
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        s.push_str(": ");
        s.push_str(&c.to_string());
        cause = c.source();
    }
    s
}
