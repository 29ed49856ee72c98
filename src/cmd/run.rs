//! `stillpoint run`: SLAM over a dataset (RGB-D, stereo or monocular, as the dataset provides),
//! with the dynamic front-end (paper figure 2) on every frame unless `--no-dynamic`. The per-frame trajectory is written as it goes (TUM), the
//! keyframe trajectory at the end, then a timing table like the paper's table 6.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use stillpoint_datasets::mcap::McapTopics;
use stillpoint_datasets::{DatasetError, DatasetKind, Frame, GroundTruthFormat, Sensor, Sequence};
use stillpoint_detect::GtDetectorParams;
use stillpoint_frontend::{DynamicFrontEnd, FrontEndSettings};
use stillpoint_image::Gray8;
use stillpoint_pipeline::{FrameTimings, Layered, Pipeline, SettingsTree};
use stillpoint_slam::System;
use stillpoint_trajectory::{Alignment, AteOptions, RpeOptions, Trajectory, TumWriter};

#[derive(clap::Args)]
pub struct Args {
    /// Sequence folder (TUM/Bonn layout, a `stillpoint synth` output, ...).
    #[arg(long, required_unless_present_any = ["bag", "video", "camera"], conflicts_with_all = ["bag", "video", "camera"])]
    pub dataset: Option<PathBuf>,
    /// A video file (H.264 in MP4) to run on, monocular: the camera from `--settings`, else a
    /// pinhole with a 60° horizontal field of view (a warning says so).
    #[arg(long, conflicts_with_all = ["bag", "camera", "kind"])]
    pub video: Option<PathBuf>,
    /// A live V4L2 camera (`/dev/video0`, MJPEG or YUYV), monocular: the trajectory is written
    /// as it goes; stop with Ctrl-C. Needs a build with the `camera` feature.
    #[arg(long, conflicts_with_all = ["bag", "kind", "realtime"])]
    pub camera: Option<PathBuf>,
    /// A ROS recording to run on instead of a folder: ROS 2 (`.mcap`, or the `ros2 bag` folder
    /// holding one) or ROS 1 (`.bag`); colour from `--rgb-topic`, depth from `--depth-topic`
    /// (monocular without), the camera from `--settings` or the recording's CameraInfo.
    #[arg(long, requires = "rgb_topic", conflicts_with = "kind")]
    pub bag: Option<PathBuf>,
    /// The recording's colour images (sensor_msgs Image or CompressedImage), e.g.
    /// /camera/color/image_raw.
    #[arg(long, requires = "bag")]
    pub rgb_topic: Option<String>,
    /// The recording's depth images registered to the colour ones (16UC1 mm or 32FC1 m), e.g.
    /// /camera/aligned_depth_to_color/image_raw.
    #[arg(long, requires = "bag")]
    pub depth_topic: Option<String>,
    /// The colour camera's CameraInfo topic; by default camera_info beside --rgb-topic.
    #[arg(long, requires = "bag")]
    pub camera_info_topic: Option<String>,
    /// YOLOX ONNX model (else the settings, $STILLPOINT_MODEL, models/ beside the binary,
    /// ../shared/models).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Dataset kind (tum, bonn, synth, kitti, euroc, folder); detected when omitted.
    #[arg(long)]
    pub kind: Option<String>,
    /// ORB-SLAM YAML or stillpoint TOML settings; the dataset's defaults when omitted.
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Per-frame trajectory (TUM format); the keyframe trajectory goes beside it (`*_keyframes.txt`).
    #[arg(long, default_value = "trajectory.txt")]
    pub out: PathBuf,
    /// Object detector for the dynamic front-end: yolox, gt (the sequence's boxes.jsonl) or none.
    #[arg(long, default_value = "yolox")]
    pub detector: String,
    /// Turn the dynamic front-end off (the ORB-SLAM3-like baseline).
    #[arg(long)]
    pub no_dynamic: bool,
    /// Run local mapping inline after each keyframe (deterministic) instead of in its own thread.
    #[arg(long)]
    pub sequential: bool,
    /// Cull exactly as the paper's algorithm 3 (static boxes protect their keypoints): without
    /// our depth-aware rule, per-keypoint motion evidence, seated-people 3D test and
    /// unknown-objects rule.
    #[arg(long)]
    pub paper_cull: bool,
    /// Only the first N frames.
    #[arg(long)]
    pub frames: Option<usize>,
    #[command(flatten)]
    pub layers: SettingsArgs,
    /// Turn loop closing off (on by default: bag-of-words detection, SE3 verification,
    /// essential-graph correction).
    #[arg(long)]
    pub no_loop_closing: bool,
    /// DBoW2 text vocabulary (ORB-SLAM's ORBvoc.txt) for loop detection; by default loop closing
    /// trains its own from the sequence's keyframes.
    #[arg(long)]
    pub vocabulary: Option<PathBuf>,
    /// Replay the sequence at its timestamps, as a live camera delivers it: frames that arrive
    /// while the system is busy are dropped (the newest waiting frame is taken); reports frames
    /// processed and dropped and the latency from arrival to pose. Local mapping runs in its
    /// own thread (not with `--sequential`).
    #[arg(long, conflicts_with = "sequential")]
    pub realtime: bool,
    /// Print a JSON summary on stdout instead of the tables.
    #[arg(long)]
    pub json: bool,
}

/// What the command line lays over the dataset's settings (`run` and `settings` share it).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SettingsArgs {
    /// stillpoint settings file (TOML; tables `slam`, `orb`, `stereo`, `front_end`, `detect`:
    /// `stillpoint settings` prints them all), laid over the defaults and `--settings`.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override one setting, `section.key=value` (repeatable; after `--config`), e.g.
    /// `--set front_end.dynamic.world.enabled=false`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
}

/// `--kind NAME` as a dataset kind (`None`: detect it).
pub fn parse_kind(kind: Option<&str>) -> anyhow::Result<Option<DatasetKind>> {
    kind.map(|k| {
        k.parse::<DatasetKind>()
            .map_err(|e| anyhow::anyhow!("--kind {k}: {e}"))
    })
    .transpose()
}

/// How one run is set up (shared with `demo` and `bench tum`).
pub struct RunOptions {
    pub dataset: PathBuf,
    pub kind: Option<DatasetKind>,
    pub settings: Option<PathBuf>,
    pub out: Option<PathBuf>,
    /// `None` = dynamic front-end off.
    pub detector: Option<String>,
    pub sequential: bool,
    pub frames: Option<usize>,
    pub progress: bool,
    /// The paper's culling only (algorithm 3; none of our culling rules).
    pub paper_cull: bool,
    /// YOLOX ONNX file; `None` searches the default places.
    pub model: Option<PathBuf>,
    /// Settings changed from their defaults on the command line.
    pub overrides: Overrides,
    /// Replay at the frames' timestamps and drop the frames that arrive while busy.
    pub realtime: bool,
}

/// What the command line changes besides the dataset and the front-end's mode.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// A stillpoint settings file (`--config`).
    pub config: Option<PathBuf>,
    /// `section.key=value` overrides (`--set`), applied after the file.
    pub sets: Vec<String>,
    /// Loop closing off (`--no-loop-closing`).
    pub no_loop_closing: bool,
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
    pub name: String,
    /// What the SLAM ran on (monocular trajectories have an arbitrary scale).
    pub sensor: Sensor,
    pub frames: usize,
    pub tracked: usize,
    pub keyframes: usize,
    pub map_points: usize,
    pub relocalisations: usize,
    pub new_maps: usize,
    pub culled_per_frame: Vec<usize>,
    pub trajectory: Trajectory,
    pub keyframe_trajectory: Trajectory,
    pub ground_truth: Option<Trajectory>,
    /// stage name -> per-frame (or per-keyframe) times in ms.
    pub timings: Vec<(&'static str, Vec<f64>)>,
    pub detector: String,
    /// With the generator's per-pixel masks (`mask/` of a `stillpoint synth --masks` sequence):
    /// keypoints handed to tracking that lie on moving objects, per frame.
    pub moving_kept_per_frame: Option<Vec<usize>>,
    /// ... and map points at the end with at least one keyframe observation on a moving object.
    pub moving_map_points: Option<usize>,
    /// Loop closing's statistics (`None` when it is off).
    pub loops: Option<stillpoint_slam::module::loop_closing::LoopStats>,
    /// With `--realtime`: what the replay at camera rate processed, dropped and how late.
    pub realtime: Option<RealtimeReport>,
    /// Why no frame could be tracked, when none was (features, depth, initialisation).
    pub untracked_reason: Option<String>,
    /// The source ended before its last frame (a cut or corrupt video, a camera gone): why.
    pub ended: Option<String>,
}

/// A replay at camera rate (`run --realtime`).
#[derive(Clone, Debug, Default)]
pub struct RealtimeReport {
    pub frames_processed: usize,
    pub frames_dropped: usize,
    /// Per processed frame: from the frame's arrival (its timestamp on the replay clock) to its
    /// pose, ms.
    pub latency_ms: Vec<f64>,
    /// Per processed frame: the pipeline's time on it, ms.
    pub processing_ms: Vec<f64>,
}

/// A camera replaying a sequence at its timestamps: frames are read ahead on their own thread
/// and handed over when due, through a channel. The consumer takes the newest frame waiting and
/// counts the ones it skips as dropped, as a live camera's driver would overwrite them.
struct ReplayCamera {
    frames: std::sync::mpsc::Receiver<(usize, Result<Frame, DatasetError>, Instant)>,
    dropped: usize,
}

impl ReplayCamera {
    fn start(seq: Box<dyn Sequence>, n: usize) -> Self {
        // Unbounded: the camera never waits for the consumer (a bounded queue would hold it back
        // and hide drops); the consumer takes all that arrived each time, so it stays short.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("replay camera".into())
            .spawn(move || {
                let start = Instant::now();
                let t0 = seq.timestamp(0).unwrap_or(0.0);
                for i in 0..n {
                    let frame = seq.frame(i);
                    let t = seq.timestamp(i).unwrap_or(t0 + i as f64 / 30.0);
                    let due = start + std::time::Duration::from_secs_f64((t - t0).max(0.0));
                    let now = Instant::now();
                    // The camera's clock: a frame exists from its timestamp on.
                    if due > now {
                        std::thread::sleep(due - now);
                    }
                    if tx.send((i, frame, due.max(now))).is_err() {
                        break;
                    }
                }
            })
            .ok();
        Self {
            frames: rx,
            dropped: 0,
        }
    }

    /// The newest frame that has arrived (waiting for the next one when none has).
    fn next(&mut self) -> Option<(usize, Result<Frame, DatasetError>, Instant)> {
        let mut newest = self.frames.recv().ok()?;
        while let Ok(newer) = self.frames.try_recv() {
            self.dropped += 1;
            newest = newer;
        }
        Some(newest)
    }
}

/// The generator's mask of frame `timestamp` (255 = moving), when the sequence has one.
fn moving_mask(dataset: &Path, timestamp: f64) -> Option<Gray8> {
    let p = dataset.join("mask").join(format!("{timestamp:.6}.png"));
    stillpoint_image::read_gray(&p).ok()
}

fn on_mask(mask: &Gray8, x: f64, y: f64) -> bool {
    mask.get_checked(x.round() as isize, y.round() as isize)
        .is_some_and(|v| v > 127)
}

/// Read a sequence's ground truth in its format. KITTI poses carry no stamps (line i is frame i):
/// they take the sequence's frame stamps (`times.txt`), so they associate with the estimate.
fn read_ground_truth(seq: &dyn Sequence, path: &Path) -> anyhow::Result<Trajectory> {
    use stillpoint_trajectory::{TrajectoryFormat, read_trajectory};
    let format = match seq.ground_truth_format() {
        GroundTruthFormat::Tum => TrajectoryFormat::Tum,
        GroundTruthFormat::KittiPoses => TrajectoryFormat::Kitti,
        GroundTruthFormat::EurocCsv => TrajectoryFormat::Euroc,
    };
    let t = read_trajectory(path, format).with_context(|| path.display().to_string())?;
    if format != TrajectoryFormat::Kitti {
        return Ok(t);
    }
    let stamps: Option<Vec<f64>> = (0..t.len()).map(|i| seq.timestamp(i)).collect();
    let stamps = stamps.with_context(|| {
        format!(
            "{}: {} poses but {} frames",
            path.display(),
            t.len(),
            seq.len()
        )
    })?;
    Ok(Trajectory::from_parts(stamps, t.poses)?)
}

fn keyframe_path(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "trajectory".into());
    out.with_file_name(format!("{stem}_keyframes.txt"))
}

/// The run's settings tree and where each value came from: the dataset's settings and the
/// crates' defaults, `--paper-cull`'s preset, the `[detect]` table of a TOML `--settings` file,
/// `--config`, then `--set`.
pub fn settings_layers(
    ds: &stillpoint_datasets::Settings,
    settings_file: Option<&Path>,
    paper_cull_preset: bool,
    overrides: &Overrides,
) -> anyhow::Result<Layered> {
    let mut base = SettingsTree::from_dataset(ds);
    if paper_cull_preset {
        paper_cull(&mut base.front_end);
    }
    let mut files: Vec<(&Path, bool)> = Vec::new();
    if let Some(p) = settings_file.filter(|p| p.extension().is_some_and(|e| e == "toml")) {
        files.push((p, true));
    }
    if let Some(p) = overrides.config.as_deref() {
        files.push((p, false));
    }
    Ok(base.layered_with(files, &overrides.sets)?)
}

/// Algorithm 3 over the paper's box verdicts: none of our rules between them and the keypoints
/// (`--set` may still turn one back on).
fn paper_cull(s: &mut FrontEndSettings) {
    s.dynamic.depth.enabled = false;
    s.dynamic.cull.unknown_objects = false;
    s.dynamic.keypoint_motion.enabled = false;
    s.seated_motion.enabled = false;
    s.dynamic.world.enabled = false;
    s.dynamic.objects.enabled = false;
}

/// Open the run's sequence: a dataset folder, or a recording's topics (`--bag`).
fn open_sequence(o: &RunOptions) -> anyhow::Result<Box<dyn Sequence>> {
    let settings = o.settings.as_deref();
    let seq = match (&o.overrides.recording, o.overrides.media) {
        (Some(topics), _) => stillpoint_datasets::open_recording(&o.dataset, topics, settings),
        (None, Some(Media::Video)) => stillpoint_datasets::open_video(&o.dataset, settings),
        (None, Some(Media::Camera)) => stillpoint_datasets::open_camera(&o.dataset, settings),
        (None, None) => stillpoint_datasets::open(&o.dataset, o.kind, settings),
    };
    seq.with_context(|| format!("opening {}", o.dataset.display()))
}

/// Run SLAM over a sequence. Frames that cannot be read are logged and skipped.
pub fn run_sequence(o: &RunOptions) -> anyhow::Result<RunSummary> {
    let seq = open_sequence(o)?;
    let ds = seq.settings().clone();
    let tree = settings_layers(&ds, o.settings.as_deref(), o.paper_cull, &o.overrides)?.tree;
    let mut pipeline_settings = tree.pipeline();
    pipeline_settings.slam.local_mapping_thread = !o.sequential;
    pipeline_settings.slam.loop_closing.enabled &= !o.overrides.no_loop_closing;
    let vocabulary = match &o.overrides.vocabulary {
        Some(p) => {
            let f = std::fs::File::open(p).with_context(|| format!("opening {}", p.display()))?;
            let v = stillpoint_slam::place::Vocabulary::from_dbow2_text(std::io::BufReader::new(f))
                .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
            tracing::info!("{}: {} words", p.display(), v.words());
            Some(v)
        }
        None => None,
    };
    // What ran: the detector's name, backend and input size (`yolox-tract 640x480`).
    let mut detector_desc = "off".to_string();
    let front = match &o.detector {
        None => None,
        Some(name) => {
            let boxes = seq.boxes();
            let mut detect = tree.detect.clone();
            if o.model.is_some() {
                detect.model = o.model.clone();
            }
            let detector = stillpoint_detect::open_detector(
                name,
                &detect,
                boxes.as_deref(),
                GtDetectorParams::default(),
            )
            .with_context(|| format!("opening the {name} detector"))?;
            detector_desc = match detector.input_size() {
                Some((h, w)) => format!("{} {w}x{h}", detector.name()),
                None => detector.name().to_string(),
            };
            let front = DynamicFrontEnd::new(detector, tree.front_end.clone());
            if tree.front_end.detector_in_background || o.realtime {
                Some(
                    front
                        .detect_in_background()
                        .with_context(|| format!("starting the {name} detector's thread"))?,
                )
            } else {
                Some(front)
            }
        }
    };
    let detector_name = detector_desc;
    if o.frames == Some(0) {
        bail!("--frames 0: nothing to run (give at least 1, or leave it out for every frame)");
    }
    let n = o.frames.map_or(seq.len(), |f| f.min(seq.len()));
    if n == 0 {
        bail!("{}: the sequence has no frames", o.dataset.display());
    }
    let _lock = o.out.as_deref().map(lock_output).transpose()?;
    let mut writer = match &o.out {
        Some(p) => Some(TumWriter::create(p).with_context(|| format!("creating {}", p.display()))?),
        None => None,
    };
    // A live source has no known end (len usize::MAX): frames are counted as they come.
    let live = seq.len() == usize::MAX;
    let bar = if o.progress {
        let b = if live {
            indicatif::ProgressBar::no_length()
        } else {
            indicatif::ProgressBar::new(n as u64)
        };
        b.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} {bar:40} {pos}/{len} frames {elapsed} ({eta} left) {msg}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    } else {
        indicatif::ProgressBar::hidden()
    };
    let mut camera = if o.realtime {
        Some(ReplayCamera::start(open_sequence(o)?, n))
    } else {
        None
    };
    let mut realtime = RealtimeReport::default();
    let pipeline_settings_init = (
        pipeline_settings.slam.init_min_keypoints,
        pipeline_settings.slam.init_min_with_depth,
        pipeline_settings.slam.init_min_cells_with_depth,
    );
    let mut pipeline = Pipeline::new(pipeline_settings, front, vocabulary);
    let mut times: Vec<FrameTimings> = Vec::with_capacity(n.min(1 << 16));
    let mut written: Option<f64> = None;
    let mut culled = Vec::with_capacity(n.min(1 << 16));
    let (mut tracked, mut relocs, mut new_maps) = (0, 0, 0);
    let has_masks = o.dataset.join("mask").is_dir();
    let mut moving_kept = Vec::new();
    let mut depth_scale_checked = false;
    // For a run that tracks nothing: what the frames offered.
    let (mut frames_read, mut frames_with_depth, mut most_keypoints) = (0usize, 0usize, 0usize);
    let mut next_index = 0;
    let mut ended = None;
    loop {
        if crate::interrupted() {
            tracing::warn!("interrupted: finishing the map and the trajectory files");
            break;
        }
        let (i, loaded, arrival) = match camera.as_mut() {
            Some(c) => match c.next() {
                Some(f) => f,
                None => break,
            },
            None if next_index < n => {
                next_index += 1;
                (next_index - 1, seq.frame(next_index - 1), Instant::now())
            }
            None => break,
        };
        bar.set_position(i as u64 + 1);
        let frame = match loaded {
            Ok(f) => f,
            // The source gives nothing after this: keep what was tracked and say why.
            Err(e @ DatasetError::Ended { .. }) => {
                ended = Some(e.to_string());
                break;
            }
            Err(e) => {
                tracing::warn!("frame {i}: skipped: {e}");
                continue;
            }
        };
        let started = Instant::now();
        frames_read += 1;
        frames_with_depth += usize::from(frame.depth.is_some() || frame.right.is_some());
        if let (false, Some(depth)) = (depth_scale_checked, &frame.depth) {
            // The first frame with depth: a wrong factor scales the whole trajectory silently.
            depth_scale_checked = true;
            let factor = seq.settings().depth_factor;
            if let Some(w) = stillpoint_datasets::depth_scale_warning(depth, factor) {
                tracing::warn!("frame {i}: {w}");
            }
        }
        let r = pipeline
            .track(&frame)
            .with_context(|| format!("{}", o.dataset.display()))?;
        if camera.is_some() {
            realtime.frames_processed += 1;
            realtime.processing_ms.push(ms_since(started));
            realtime.latency_ms.push(ms_since(arrival));
        }
        let n_culled = r.culled();
        most_keypoints = most_keypoints.max(r.keypoints.len() - n_culled);
        culled.push(n_culled);
        if has_masks {
            let mask = moving_mask(&o.dataset, frame.timestamp);
            moving_kept.push(mask.map_or(0, |m| {
                r.keypoints
                    .iter()
                    .zip(&r.dynamic)
                    .filter(|(k, d)| !**d && on_mask(&m, k[0] as f64, k[1] as f64))
                    .count()
            }));
        }
        tracing::debug!(
            frame = i,
            state = ?r.state,
            keypoints = r.keypoints.len() - n_culled,
            culled = n_culled,
            inliers = r.inliers,
            keyframe = r.new_keyframe,
            "tracked"
        );
        relocs += r.relocalised as usize;
        new_maps += r.new_map as usize;
        if let Some(p) = r.pose_wc {
            tracked += 1;
            if written.is_none_or(|l| frame.timestamp > l) {
                written = Some(frame.timestamp);
                if let Some(w) = writer.as_mut() {
                    w.write(frame.timestamp, &p)
                        .with_context(|| format!("writing frame {i}"))?;
                }
            }
        }
        bar.set_message(format!(
            "{:?}, {} kf",
            r.state,
            pipeline.system().keyframe_count()
        ));
        times.push(r.timings);
    }
    bar.finish_and_clear();
    let fin = pipeline.finish().context("local mapping")?;
    // The file written as we went (tracking's poses: what a crash leaves) is replaced by the
    // frames following their keyframes as bundle adjustment and loop closing left them.
    if let Some(p) = &o.out {
        stillpoint_trajectory::write_tum(p, &fin.trajectory)
            .with_context(|| format!("rewriting {}", p.display()))?;
        if fin.loop_closed {
            tracing::info!("loop closed: trajectory rebuilt through the keyframes");
        }
    }
    if let Some(p) = &o.out {
        let kp = keyframe_path(p);
        stillpoint_trajectory::write_tum(&kp, &fin.keyframe_trajectory)
            .with_context(|| format!("writing {}", kp.display()))?;
    }
    let ground_truth = seq.ground_truth().and_then(|p| {
        read_ground_truth(seq.as_ref(), &p)
            .map_err(|e| tracing::warn!("ground truth unreadable: {e:#}"))
            .ok()
    });
    let moving_map_points = has_masks.then(|| count_moving_points(&fin.system, &o.dataset));
    if let Some(c) = &camera {
        realtime.frames_dropped = c.dropped;
    }
    let pick = |f: fn(&FrameTimings) -> f64| times.iter().map(f).collect::<Vec<f64>>();
    let mut timings = vec![];
    if o.detector.is_some() {
        timings.push(("semantic", pick(|t| t.semantic_ms)));
        timings.push(("geometry", pick(|t| t.geometry_ms)));
    }
    timings.push(("orb", pick(|t| t.orb_ms)));
    timings.push(("tracking", pick(|t| t.tracking_ms)));
    let loops = fin.loops;
    timings.push(("local mapping (per keyframe)", fin.mapping_ms));
    if let Some(l) = &loops {
        timings.push(("loop detection (per keyframe)", l.detection_ms.clone()));
        timings.push(("loop correction", l.correction_ms.clone()));
        timings.push(("global BA after a loop", l.global_ba_ms.clone()));
        timings.push(("vocabulary training", l.training_ms.clone()));
    }
    Ok(RunSummary {
        name: seq.name(),
        sensor: ds.sensor,
        frames: if live { frames_read } else { n },
        tracked,
        keyframes: fin.keyframes,
        map_points: fin.map_points,
        relocalisations: relocs,
        new_maps,
        culled_per_frame: culled,
        trajectory: fin.trajectory,
        keyframe_trajectory: fin.keyframe_trajectory,
        ground_truth,
        timings,
        detector: detector_name,
        moving_kept_per_frame: has_masks.then_some(moving_kept),
        moving_map_points,
        loops,
        realtime: camera.is_some().then_some(realtime),
        ended,
        untracked_reason: (tracked == 0).then(|| {
            let init = &pipeline_settings_init;
            if frames_read == 0 {
                "no frame could be read".to_string()
            } else if ds.sensor != Sensor::Mono && frames_with_depth == 0 {
                format!(
                    "none of the {frames_read} frames had depth (an RGB-D map starts from depth: \
                     check depth.txt and the depth images)"
                )
            } else if most_keypoints < init.0 {
                format!(
                    "the most keypoints a frame kept was {most_keypoints}; a map starts with \
                     {} (slam.init_min_keypoints; plain or dark images, or the front-end culled them)",
                    init.0
                )
            } else {
                format!(
                    "the map never started: up to {most_keypoints} keypoints a frame, but fewer than \
                     {} with depth, or spread over fewer than {} of the 16 image cells",
                    init.1, init.2
                )
            }
        }),
    })
}

/// An exclusive lock on the trajectory file for the whole run, taken before the file is
/// emptied: a second run given the same `--out` fails at once instead of writing into it.
fn lock_output(path: &Path) -> anyhow::Result<std::fs::File> {
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)
        .with_context(|| format!("opening {}", path.display()))?;
    match file.try_lock() {
        Ok(()) => Ok(file),
        Err(std::fs::TryLockError::WouldBlock) => bail!(
            "{}: another run is writing this trajectory (give each run its own --out)",
            path.display()
        ),
        Err(std::fs::TryLockError::Error(e)) => {
            Err(e).with_context(|| format!("locking {}", path.display()))
        }
    }
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Good map points with a keyframe observation on the generator's moving mask.
fn count_moving_points(sys: &System, dataset: &Path) -> usize {
    let Ok(map) = sys.map().lock().map(|m| m.clone()) else {
        return 0;
    };
    let mut moving = std::collections::BTreeSet::new();
    let mut created = std::collections::BTreeSet::new();
    for kf in map.keyframes.values().filter(|k| !k.bad) {
        let Some(mask) = moving_mask(dataset, kf.timestamp) else {
            continue;
        };
        let before = created.len();
        for (i, mp) in kf.map_points.iter().enumerate() {
            if let Some(mp) = mp
                && on_mask(&mask, kf.points[i].x, kf.points[i].y)
                && let Some(p) = map.points.get(mp).filter(|p| !p.bad)
            {
                moving.insert(*mp);
                if p.first_kf == kf.id {
                    created.insert(*mp);
                    tracing::trace!(
                        "keyframe {} point {mp} created on a mover at ({:.0}, {:.0}) depth {:.2}",
                        kf.id,
                        kf.points[i].x,
                        kf.points[i].y,
                        kf.depth.get(i).copied().unwrap_or(0.0)
                    );
                }
            }
        }
        if created.len() > before {
            tracing::debug!(
                "keyframe {} (frame at {:.3}): {} map points created on movers",
                kf.id,
                kf.timestamp,
                created.len() - before
            );
        }
    }
    tracing::info!(
        "map points on moving objects: {} ({} created there), {} observations",
        moving.len(),
        created.len(),
        map.points
            .values()
            .filter(|p| !p.bad)
            .map(|p| p.observations.len())
            .sum::<usize>()
    );
    moving.len()
}

impl RunSummary {
    /// mean / median / p90 of the keypoints the front-end culled per frame.
    pub fn culled_stats(&self) -> (f64, f64, f64) {
        let culled: Vec<f64> = self.culled_per_frame.iter().map(|&c| c as f64).collect();
        stats(&culled)
    }
}

/// mean / median / p90 of a list (0s when empty).
pub fn stats(v: &[f64]) -> (f64, f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let mean = s.iter().sum::<f64>() / s.len() as f64;
    (mean, quantile(&s, 0.5), quantile(&s, 0.9))
}

/// The value at quantile `q` (0..1, nearest rank) of sorted values; 0 when there are none.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let last = sorted.len().saturating_sub(1);
    sorted
        .get((last as f64 * q).round() as usize)
        .copied()
        .unwrap_or(0.0)
}

/// How a run's trajectory is aligned to the ground truth: SE(3), as the paper, or Sim(3) for a
/// monocular run, whose scale is arbitrary (evo `-as`).
pub fn alignment(s: &RunSummary) -> Alignment {
    if s.sensor == Sensor::Mono {
        Alignment::Sim3
    } else {
        Alignment::Se3
    }
}

/// ATE and translational RPE over 1 s ([`alignment`]: SE(3), or Sim(3) for monocular), when there
/// is ground truth.
pub fn accuracy(
    s: &RunSummary,
) -> Option<(
    stillpoint_trajectory::AteResult,
    Option<stillpoint_trajectory::RpeResult>,
)> {
    let gt = s.ground_truth.as_ref()?;
    let ate = stillpoint_trajectory::ate(
        gt,
        &s.trajectory,
        &AteOptions {
            align: alignment(s),
            ..Default::default()
        },
    )
    .map_err(|e| tracing::warn!("ATE: {e}"))
    .ok()?;
    let rpe = stillpoint_trajectory::rpe(
        gt,
        &s.trajectory,
        &RpeOptions {
            align: if s.sensor == Sensor::Mono {
                Alignment::Sim3
            } else {
                Alignment::None
            },
            delta: 1.0,
            delta_unit: stillpoint_trajectory::DeltaUnit::Seconds,
            ..Default::default()
        },
    )
    .map_err(|e| tracing::warn!("RPE: {e}"))
    .ok();
    Some((ate, rpe))
}

/// The ground-truth pose nearest to `t` (within 0.02 s, the TUM tools' association window).
fn gt_pose_at(gt: &Trajectory, t: f64) -> Option<stillpoint_geometry::Se3> {
    let i = gt
        .stamps
        .iter()
        .enumerate()
        .min_by(|a, b| (a.1 - t).abs().total_cmp(&(b.1 - t).abs()))?
        .0;
    ((gt.stamps[i] - t).abs() <= 0.02).then(|| gt.poses[i])
}

/// Loop closing in the JSON summary: counts, and per loop the frames and how far apart the two
/// keyframes truly are (ground truth), which tells a true revisit from a false loop.
fn loops_json(s: &RunSummary) -> serde_json::Value {
    let Some(l) = &s.loops else {
        return serde_json::Value::Null;
    };
    let events: Vec<serde_json::Value> = l
        .loops
        .iter()
        .map(|e| {
            let truth = s.ground_truth.as_ref().and_then(|gt| {
                let (a, b) = (
                    gt_pose_at(gt, e.timestamp)?,
                    gt_pose_at(gt, e.loop_timestamp)?,
                );
                Some((
                    (a.translation.vector - b.translation.vector).norm(),
                    a.rotation.angle_to(&b.rotation).to_degrees(),
                ))
            });
            serde_json::json!({
                "frame": e.frame_index, "loop_frame": e.loop_frame_index,
                "keyframe": e.keyframe, "loop_keyframe": e.loop_keyframe,
                "ransac_inliers": e.ransac_inliers, "refined_inliers": e.refined_inliers,
                "loop_matches": e.loop_matches,
                "correction_m": e.correction_m, "correction_deg": e.correction_deg,
                "graph_keyframes": e.graph_keyframes, "graph_edges": e.graph_edges,
                "correction_ms": e.correction_ms,
                "gt_distance_m": truth.map(|t| t.0), "gt_angle_deg": truth.map(|t| t.1),
            })
        })
        .collect();
    serde_json::json!({
        "loops": l.loops.len(),
        "candidates_tried": l.tried_candidates,
        "candidates_rejected": l.rejected_candidates,
        "vocabulary_trainings": l.training_ms.len(),
        "vocabulary_words": l.vocabulary_words,
        "events": events,
    })
}

pub fn summary_json(s: &RunSummary) -> serde_json::Value {
    let acc = accuracy(s);
    let ate_keyframes = s.ground_truth.as_ref().and_then(|gt| {
        stillpoint_trajectory::ate(
            gt,
            &s.keyframe_trajectory,
            &AteOptions {
                align: Alignment::Se3,
                ..Default::default()
            },
        )
        .ok()
    });
    let timing: serde_json::Map<String, serde_json::Value> = s
        .timings
        .iter()
        .map(|(k, v)| {
            let (mean, median, p90) = stats(v);
            (
                k.to_string(),
                serde_json::json!({"mean_ms": mean, "median_ms": median, "p90_ms": p90, "count": v.len()}),
            )
        })
        .collect();
    let (cm, cmed, cp90) = s.culled_stats();
    serde_json::json!({
        "sequence": s.name,
        "sensor": s.sensor,
        "detector": s.detector,
        "frames": s.frames,
        "tracked": s.tracked,
        "keyframes": s.keyframes,
        "keyframe_poses_written": s.keyframe_trajectory.len(),
        "map_points": s.map_points,
        "relocalisations": s.relocalisations,
        "new_maps": s.new_maps,
        "culled_per_frame": {"mean": cm, "median": cmed, "p90": cp90},
        "ate": acc.as_ref().map(|(a, _)| serde_json::json!({
            "align": alignment(s), "scale": a.alignment.scale,
            "rmse": a.stats.rmse, "mean": a.stats.mean, "median": a.stats.median,
            "std": a.stats.std, "max": a.stats.max, "pairs": a.stats.count})),
        "rpe_1s": acc.as_ref().and_then(|(_, r)| r.as_ref()).map(|r| serde_json::json!({
            "trans_rmse": r.translation.rmse, "trans_std": r.translation.std,
            "rot_rmse_deg": r.rotation_deg.rmse})),
        "timing": timing,
        "moving_keypoints_kept_per_frame": s.moving_kept_per_frame.as_ref().map(|v| {
            let v: Vec<f64> = v.iter().map(|&c| c as f64).collect();
            let (m, med, p90) = stats(&v);
            serde_json::json!({"mean": m, "median": med, "p90": p90})
        }),
        "moving_map_points": s.moving_map_points,
        "ate_keyframes": ate_keyframes.map(|a| serde_json::json!({"rmse": a.stats.rmse, "pairs": a.stats.count})),
        "loop_closing": loops_json(s),
        "realtime": s.realtime.as_ref().map(|r| realtime_json(r, acc.as_ref().map(|(a, _)| a.stats.rmse))),
    })
}

/// The replay at camera rate in the JSON summary (`frames_processed`, `frames_dropped`,
/// `latency_ms`, `ate_m` as the README states them).
fn realtime_json(r: &RealtimeReport, ate_m: Option<f64>) -> serde_json::Value {
    let [median, p95, max] = r.latency_quantiles();
    serde_json::json!({
        "frames_processed": r.frames_processed,
        "frames_dropped": r.frames_dropped,
        "latency_ms": {"median": median, "p95": p95, "max": max},
        "processing_ms_mean": stats(&r.processing_ms).0,
        "ate_m": ate_m,
    })
}

impl RealtimeReport {
    /// Latency median, p95 and max, ms.
    fn latency_quantiles(&self) -> [f64; 3] {
        let mut s = self.latency_ms.clone();
        s.sort_by(f64::total_cmp);
        [0.5, 0.95, 1.0].map(|q| quantile(&s, q))
    }
}

pub fn print_summary(s: &RunSummary) {
    println!(
        "{}: {} of {} frames tracked, {} keyframes, {} map points, {} relocalisations, {} new maps (detector: {})",
        s.name,
        s.tracked,
        s.frames,
        s.keyframes,
        s.map_points,
        s.relocalisations,
        s.new_maps,
        s.detector
    );
    if let Some((a, r)) = accuracy(s) {
        print!(
            "ATE RMSE {:.4} m (S.D. {:.4}, {} pairs{})",
            a.stats.rmse,
            a.stats.std,
            a.stats.count,
            if alignment(s) == Alignment::Sim3 {
                format!(", Sim(3)-aligned, scale {:.3}", a.alignment.scale)
            } else {
                String::new()
            }
        );
        if let Some(r) = r {
            print!(
                ", RPE (1 s) trans RMSE {:.4} m (S.D. {:.4})",
                r.translation.rmse, r.translation.std
            );
        }
        println!();
    }
    println!(
        "{:<30} {:>9} {:>9} {:>9}",
        "stage", "mean ms", "median", "p90"
    );
    // Stages that never ran (no loop closed: no correction) have no row.
    for (k, v) in s.timings.iter().filter(|(_, v)| !v.is_empty()) {
        let (m, med, p90) = stats(v);
        println!("{k:<30} {m:>9.2} {med:>9.2} {p90:>9.2}");
    }
    print_culled_row(s);
    if let Some(r) = &s.realtime {
        let [median, p95, max] = r.latency_quantiles();
        println!(
            "real time: {} frames processed, {} dropped; latency median {median:.1} ms, p95 {p95:.1}, max {max:.1}; {:.1} ms a processed frame",
            r.frames_processed,
            r.frames_dropped,
            stats(&r.processing_ms).0,
        );
    }
    if let Some(l) = &s.loops {
        println!("loops closed: {}", l.loops.len());
        for e in &l.loops {
            println!(
                "  frame {} -> frame {} ({} matches, keyframe moved {:.3} m / {:.2} deg)",
                e.frame_index, e.loop_frame_index, e.loop_matches, e.correction_m, e.correction_deg
            );
        }
    }
}

/// The "keypoints culled / frame" row of the text stage tables (`run`, `demo`).
pub fn print_culled_row(s: &RunSummary) {
    let (m, med, p90) = s.culled_stats();
    println!(
        "{:<30} {m:>9.1} {med:>9.1} {p90:>9.1}",
        "keypoints culled / frame"
    );
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let kind = parse_kind(args.kind.as_deref())?;
    // clap requires one of them.
    let Some(dataset) = (args.dataset.clone())
        .or(args.bag.clone())
        .or(args.video.clone())
        .or(args.camera.clone())
    else {
        bail!("give --dataset DIR, --bag FILE, --video FILE or --camera DEVICE");
    };
    let media = match (&args.video, &args.camera) {
        (Some(_), _) => Some(Media::Video),
        (None, Some(_)) => Some(Media::Camera),
        _ => None,
    };
    let recording = args.rgb_topic.clone().map(|rgb| McapTopics {
        rgb,
        depth: args.depth_topic.clone(),
        camera_info: args.camera_info_topic.clone(),
    });
    let o = RunOptions {
        dataset,
        kind,
        settings: args.settings.clone(),
        out: Some(args.out.clone()),
        detector: (!args.no_dynamic).then(|| args.detector.clone()),
        sequential: args.sequential,
        realtime: args.realtime,
        frames: args.frames,
        model: args.model.clone(),
        progress: true,
        paper_cull: args.paper_cull,
        overrides: Overrides {
            config: args.layers.config.clone(),
            sets: args.layers.sets.clone(),
            no_loop_closing: args.no_loop_closing,
            vocabulary: args.vocabulary.clone(),
            recording,
            media,
        },
    };
    let s = run_sequence(&o)?;
    tracing::info!(
        "trajectory written to {} (keyframes: {})",
        args.out.display(),
        keyframe_path(&args.out).display()
    );
    if args.json {
        println!("{}", summary_json(&s));
    } else {
        print_summary(&s);
    }
    if let Some(why) = &s.ended {
        bail!(
            "{why} ({} of the {} frames before it tracked; the trajectory and keyframe files are complete)",
            s.tracked,
            s.culled_per_frame.len()
        );
    }
    if s.tracked == 0 {
        match &s.untracked_reason {
            Some(why) => bail!("no frame could be tracked: {why}"),
            None => bail!("no frame could be tracked"),
        }
    }
    if crate::interrupted() {
        bail!(
            "interrupted after {} of {} frames; the trajectory and keyframe files are complete",
            s.culled_per_frame.len(),
            s.frames
        );
    }
    Ok(())
}
