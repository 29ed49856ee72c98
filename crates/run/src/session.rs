//! The run itself: settings, detector and front-end, the frame loop, the files, the summary.

use std::path::Path;
use std::sync::atomic::Ordering;
use std::time::Instant;

use stillpoint_core::ms_since;

use stillpoint_datasets::{Frame, Sensor, Sequence};
use stillpoint_detect::GtDetectorParams;
use stillpoint_frontend::{DynamicFrontEnd, FrontEnd, FrontEndSettings};
use stillpoint_pipeline::{FrameResult, FrameTimings, Pipeline};
use stillpoint_slam::SlamSettings;
use stillpoint_slam::map_file::MapFile;
use stillpoint_slam::place::Vocabulary;

use crate::output::lock_output;
use crate::read_ahead::ReadAhead;
use crate::replay::{Arrival, RealtimeReport, ReplayCamera};
use crate::sink::{
    DenseCloud, Ended, MapCloud, MovingPixels, Overlays, Recording, SavedMap, Sink, Tracked,
    TrajectoryFile,
};
use crate::{
    Layered, MapFileReport, MapFilesReport, Media, Overrides, RunError, RunOptions, RunSummary,
    SettingsTree,
};

/// What a run reports as it goes, for a progress display.
pub enum Event<'a> {
    /// Frame `index` of `frames` is next (also for a frame that turns out unreadable).
    Next {
        /// The frame's position in the sequence.
        index: usize,
        /// Frames the run will take at most.
        frames: usize,
    },
    /// What tracking made of a frame, and the keyframes in the map after it.
    Tracked {
        /// The frame's result.
        result: &'a FrameResult,
        /// Keyframes in the map.
        keyframes: usize,
    },
    /// No more frames: the map and the files are being finished.
    Finishing,
}

/// The run's settings tree and where each value came from: the dataset's settings and the
/// crates' defaults, the paper-cull preset, the `[detect]` table of a TOML `settings_file`, the
/// overrides' `config` file, then their `sets`.
pub fn settings_layers(
    ds: &stillpoint_datasets::Settings,
    settings_file: Option<&Path>,
    paper_cull_preset: bool,
    overrides: &Overrides,
) -> Result<Layered, RunError> {
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
    s.dynamic.judge.ata_ignores_person_points_without_depth = false;
    s.dynamic.keypoint_motion.enabled = false;
    s.seated_motion.enabled = false;
    s.dynamic.world.enabled = false;
    s.dynamic.objects.enabled = false;
}

/// Open the run's sequence: a dataset folder, a recording's topics, a video or a camera.
fn open_sequence(o: &RunOptions) -> Result<Box<dyn Sequence>, RunError> {
    let settings = o.settings.as_deref();
    let seq = match (&o.overrides.recording, o.overrides.media) {
        (Some(topics), _) => stillpoint_datasets::open_recording(&o.dataset, topics, settings),
        (None, Some(Media::Video)) => stillpoint_datasets::open_video(&o.dataset, settings),
        (None, Some(Media::Camera)) => stillpoint_datasets::open_camera(&o.dataset, settings),
        (None, None) => stillpoint_datasets::open(&o.dataset, o.kind, settings),
    };
    seq.map_err(|source| RunError::Open {
        path: o.dataset.clone(),
        source,
    })
}

/// A DBoW2 text vocabulary (ORB-SLAM's ORBvoc.txt).
fn read_vocabulary(p: &Path) -> Result<stillpoint_slam::place::Vocabulary, RunError> {
    let f = std::fs::File::open(p).map_err(|source| RunError::Io {
        context: format!("opening {}", p.display()),
        source,
    })?;
    let v = stillpoint_slam::place::Vocabulary::from_dbow2_text(std::io::BufReader::new(f))
        .map_err(|msg| RunError::Vocabulary {
            path: p.to_path_buf(),
            msg,
        })?;
    tracing::info!("{}: {} words", p.display(), v.words());
    Ok(v)
}

/// Run SLAM over a sequence with the outputs [`RunOptions`] asks for. Frames that cannot be
/// read are logged and skipped. `progress` hears of each frame ([`Event`]).
pub fn run_sequence(
    o: &RunOptions,
    progress: &mut dyn FnMut(Event),
) -> Result<RunSummary, RunError> {
    run_with(o, None, &mut [], progress)
}

/// [`run_sequence`], with the caller's own sinks after the run's (each hears every frame and
/// the end) and, for a caller that scores the run, the sequence's truth about moving pixels
/// (the dense cloud counts its points on movers with it).
pub fn run_with(
    o: &RunOptions,
    truth: Option<&dyn MovingPixels>,
    sinks: &mut [&mut dyn Sink],
    progress: &mut dyn FnMut(Event),
) -> Result<RunSummary, RunError> {
    run_source(o, open_sequence(o)?, truth, sinks, progress)
}

/// [`run_with`] over a sequence the caller opened (a live source of its own, such as a ROS 2
/// subscription): `o.dataset` only names it in messages, and `o.realtime` must be off (the
/// replay reopens `o.dataset`).
pub fn run_source(
    o: &RunOptions,
    seq: Box<dyn Sequence>,
    truth: Option<&dyn MovingPixels>,
    sinks: &mut [&mut dyn Sink],
    progress: &mut dyn FnMut(Event),
) -> Result<RunSummary, RunError> {
    let ds = seq.settings().clone();
    let layers = settings_layers(&ds, o.settings.as_deref(), o.paper_cull, &o.overrides)?;
    let tree = layers.tree;
    let mut settings = tree.pipeline();
    // A recording is not a race: mapped inline, its trajectory is the same however busy the
    // machine is (on its own thread, a mapper that falls behind leaves tracking without the
    // points of the last keyframes, and a monocular run then loses them). A camera and
    // `--realtime` cannot wait for the mapper: they map on its own thread unless the settings
    // say otherwise. A live source has no known end (len usize::MAX).
    let live = seq.len() == usize::MAX;
    if !layers.sources.contains_key("slam.local_mapping_thread") {
        settings.slam.local_mapping_thread = live || o.realtime;
    }
    let slam = settings.slam.clone();
    let vocabulary = o
        .overrides
        .vocabulary
        .as_deref()
        .map(read_vocabulary)
        .transpose()?;
    // Read and checked before the detector opens: a wrong map fails at once.
    let loaded = load_map(o, &slam, vocabulary.as_ref())?;
    let (front, detector) = open_front_end(o, &tree, seq.as_ref(), live || o.realtime)?;
    let n = frames_to_run(o, seq.len())?;
    let _lock = o.out.as_deref().map(lock_output).transpose()?;
    let mut outputs = Outputs::open(o, &tree, &slam, truth)?;
    let started = std::time::Instant::now();
    // A recording's frames decoded ahead of the pipeline; a camera's are taken as they come.
    let ahead = if live || o.realtime {
        0
    } else {
        tree.read.ahead_frames
    };
    let mut map_files = MapFilesReport::default();
    let mut pipeline = match loaded {
        Some((path, file, report)) => {
            map_files.loaded = Some(report);
            let mode = if o.localize {
                stillpoint_slam::LoadedMapMode::Localize
            } else {
                stillpoint_slam::LoadedMapMode::Extend
            };
            Pipeline::with_map(settings, front, vocabulary, file, mode)
                .map_err(|source| RunError::MapFile { path, source })?
        }
        None => Pipeline::new(settings, front, vocabulary),
    };
    // The reader hands each scheduled frame to the detector as it decodes it.
    let (reader, seq) = ReadAhead::start(seq, n, ahead, pipeline.frame_prefetch());
    let mut feed = Feed::start(o, seq.as_ref(), n, &tree, reader)?;
    let mut tally = Tally::new(n, feed.is_replay());
    let mut ended = None;
    let mut asked = Instant::now();
    while let Some((i, loaded, arrival)) = feed.next(o) {
        if !feed.is_replay() {
            // A replay's frames wait for the camera's clock, not for the reader.
            tally.reading_ms.push(ms_since(asked));
        }
        progress(Event::Next {
            index: i,
            frames: n,
        });
        let frame = match loaded {
            Ok(f) => f,
            // The source gives nothing after this: keep what was tracked and say why.
            Err(e @ stillpoint_datasets::DatasetError::Ended { .. }) => {
                ended = Some(e.to_string());
                break;
            }
            Err(e) => {
                tracing::warn!("frame {i}: skipped: {e}");
                asked = Instant::now();
                continue;
            }
        };
        let started = Instant::now();
        tally.read(&frame, ds.depth_factor);
        let r = pipeline
            .track(&frame)
            .map_err(|source| RunError::Pipeline {
                context: format!("{}", o.dataset.display()),
                source,
            })?;
        tally.tracked(&r, started, arrival);
        let step = Tracked {
            frame: &frame,
            result: &r,
            system: pipeline.system(),
        };
        for sink in outputs.sinks() {
            sink.frame(&step)?;
        }
        for sink in sinks.iter_mut() {
            sink.frame(&step)?;
        }
        let keyframes = pipeline.system().keyframe_count();
        progress(Event::Tracked {
            result: &r,
            keyframes,
        });
        feed.done_with(frame);
        asked = Instant::now();
    }
    progress(Event::Finishing);
    let fin = pipeline.finish().map_err(|source| RunError::Pipeline {
        context: "local mapping".into(),
        source,
    })?;
    let end = Ended {
        finished: &fin,
        sequence: seq.as_ref(),
        map_loaded: map_files.loaded.is_some(),
    };
    for sink in outputs.sinks() {
        sink.finish(&end)?;
    }
    for sink in sinks.iter_mut() {
        sink.finish(&end)?;
    }
    map_files.saved = outputs.saved_map.and_then(|m| m.report);
    if let Some(r) = tally.realtime.as_mut() {
        r.frames_dropped = feed.dropped();
    }
    let untracked_reason = (tally.tracked == 0).then(|| tally.untracked_reason(o, &ds, &slam));
    let mut timings = tally.stage_times(o.detector.is_some(), slam.local_mapping_thread);
    timings.push(("local mapping (per keyframe)", fin.mapping_ms));
    let record = outputs.recording.map(|r| {
        timings.push(("recording", r.ms));
        r.report
    });
    if let Some(l) = &fin.loops {
        timings.push(("loop detection (per keyframe)", l.detection_ms.clone()));
        timings.push(("loop correction", l.correction_ms.clone()));
        timings.push(("global BA after a loop", l.global_ba_ms.clone()));
        timings.push(("vocabulary training", l.training_ms.clone()));
    }
    Ok(RunSummary {
        name: seq.name(),
        sensor: ds.sensor,
        frames: if live { tally.frames_read } else { n },
        tracked: tally.tracked + fin.placed_at_end,
        keyframes: fin.keyframes,
        map_points: fin.map_points,
        relocalisations: tally.relocalisations,
        new_maps: tally.new_maps,
        maps: fin.maps.clone(),
        culled_per_frame: tally.culled,
        culled_matched_per_frame: tally.culled_matched,
        trajectory: fin.trajectory,
        keyframe_trajectory: fin.keyframe_trajectory,
        timings,
        wall_s: started.elapsed().as_secs_f64(),
        detector,
        loops: fin.loops,
        realtime: tally.realtime,
        ended,
        dense: outputs.dense.and_then(|d| d.report),
        first_relocalisation: tally.first_relocalisation,
        map_files,
        record: record.flatten(),
        untracked_reason,
    })
}

/// `--frames` against the sequence's length: how many frames the run takes.
fn frames_to_run(o: &RunOptions, len: usize) -> Result<usize, RunError> {
    if o.frames == Some(0) {
        return Err(RunError::Refused(
            "--frames 0: nothing to run (give at least 1, or leave it out for every frame)".into(),
        ));
    }
    let n = o.frames.map_or(len, |f| f.min(len));
    if n == 0 {
        return Err(RunError::Refused(format!(
            "{}: the sequence has no frames",
            o.dataset.display()
        )));
    }
    Ok(n)
}

/// `--load-map`: the map file read and checked against the run's settings and vocabulary.
fn load_map(
    o: &RunOptions,
    slam: &SlamSettings,
    vocabulary: Option<&Vocabulary>,
) -> Result<Option<(std::path::PathBuf, MapFile, MapFileReport)>, RunError> {
    if o.localize && o.load_map.is_none() {
        return Err(RunError::Refused(
            "--localize needs a map to localise in (--load-map FILE)".into(),
        ));
    }
    let Some(path) = &o.load_map else {
        return Ok(None);
    };
    let t0 = Instant::now();
    let map_error = |source| RunError::MapFile {
        path: path.clone(),
        source,
    };
    let bytes = std::fs::read(path).map_err(|e| map_error(e.into()))?;
    let file = stillpoint_slam::map_file::decode(&bytes).map_err(map_error)?;
    file.check_settings(slam).map_err(map_error)?;
    if let Some(v) = vocabulary {
        file.check_vocabulary(v).map_err(map_error)?;
    }
    let report = MapFileReport {
        keyframes: file.map.keyframes.len(),
        map_points: file.map.points.len(),
        bytes: bytes.len(),
        ms: ms_since(t0),
    };
    tracing::info!(
        "{}: {} keyframes, {} map points ({} bytes, read in {:.1} ms){}",
        path.display(),
        report.keyframes,
        report.map_points,
        report.bytes,
        report.ms,
        if o.localize {
            "; localising in it"
        } else {
            "; mapping on in it"
        }
    );
    Ok(Some((path.clone(), file, report)))
}

/// The detector and the dynamic front-end over it (none without a detector), and what detects:
/// its name, backend and input size (`yolox-tract 640x480`), or `off`.
fn open_front_end(
    o: &RunOptions,
    tree: &SettingsTree,
    seq: &dyn Sequence,
    live: bool,
) -> Result<(Option<Box<dyn FrontEnd>>, String), RunError> {
    let Some(name) = &o.detector else {
        return Ok((None, "off".to_string()));
    };
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
    .map_err(|source| RunError::Detector {
        context: format!("opening the {name} detector"),
        source,
    })?;
    let described = match detector.input_size() {
        Some((h, w)) => format!("{} {w}x{h}", detector.name()),
        None => detector.name().to_string(),
    };
    let mut settings = tree.front_end.clone();
    // A live run (camera, ROS 2, `--realtime`) never waits for the detector: its schedule of
    // frames is for recordings.
    if live {
        settings.background_detect_every_frames = 0;
    }
    // A recording's YOLOX works beside tracking on a schedule of frames; monocular once its
    // map stands (a monocular start waits for each frame's own boxes: carried ones cost
    // living_turn seed 3 half its frames). Ground-truth boxes cost nothing: they stay inline.
    let monocular = seq.settings().sensor == stillpoint_datasets::Sensor::Mono;
    let on_schedule = !live
        && settings.detect_recordings_on_schedule
        && settings.background_detect_every_frames > 0
        && name == "yolox"
        && (!monocular || settings.detect_monocular_recordings_on_schedule);
    if monocular {
        settings.background_detect_lag_frames = settings.background_detect_lag_frames_monocular;
        settings.background_detect_ahead = settings.background_detect_ahead_monocular;
    }
    let in_background = settings.detector_in_background || o.realtime || on_schedule;
    let front = DynamicFrontEnd::new(detector, settings);
    let front = if in_background {
        front
            .detect_in_background()
            .map_err(|source| RunError::Detector {
                context: format!("starting the {name} detector's thread"),
                source,
            })?
    } else {
        front
    };
    Ok((Some(Box::new(front)), described))
}

/// The outputs [`RunOptions`] asks for, each a [`Sink`].
struct Outputs<'a> {
    trajectory: Option<TrajectoryFile>,
    overlays: Option<Overlays>,
    recording: Option<Recording>,
    dense: Option<DenseCloud<'a>>,
    map_cloud: Option<MapCloud>,
    saved_map: Option<SavedMap>,
}

impl<'a> Outputs<'a> {
    fn open(
        o: &RunOptions,
        tree: &SettingsTree,
        slam: &SlamSettings,
        truth: Option<&'a dyn MovingPixels>,
    ) -> Result<Self, RunError> {
        if let Some(dir) = &o.overlay {
            std::fs::create_dir_all(dir).map_err(|source| RunError::Io {
                context: format!("creating {}", dir.display()),
                source,
            })?;
        }
        let recording = match &o.record {
            Some(path) => Some(Recording {
                path: path.clone(),
                recorder: Some(crate::record::Recorder::create(path, &tree.record)?),
                camera: slam.camera,
                ms: Vec::new(),
                report: None,
            }),
            None => None,
        };
        Ok(Self {
            recording,
            trajectory: o.out.as_deref().map(TrajectoryFile::create).transpose()?,
            overlays: o.overlay.clone().map(|dir| Overlays { dir }),
            dense: o.dense_cloud.clone().map(|path| DenseCloud {
                path,
                fusion: stillpoint_pipeline::dense::DenseFusion::new(
                    tree.dense.clone(),
                    slam.camera,
                ),
                truth,
                report: None,
            }),
            map_cloud: o.map_cloud.clone().map(|path| MapCloud { path }),
            saved_map: o
                .save_map
                .clone()
                .map(|path| SavedMap { path, report: None }),
        })
    }

    /// Each output, in the order they finish: the trajectory first (what matters most if a
    /// later one fails), the recording last (it takes the final map).
    fn sinks(&mut self) -> impl Iterator<Item = &mut dyn Sink> {
        let trajectory = self.trajectory.as_mut().map(|s| s as &mut dyn Sink);
        let overlays = self.overlays.as_mut().map(|s| s as &mut dyn Sink);
        let dense = self.dense.as_mut().map(|s| s as &mut dyn Sink);
        let map_cloud = self.map_cloud.as_mut().map(|s| s as &mut dyn Sink);
        let saved_map = self.saved_map.as_mut().map(|s| s as &mut dyn Sink);
        let recording = self.recording.as_mut().map(|s| s as &mut dyn Sink);
        [trajectory, overlays, dense, map_cloud, saved_map, recording]
            .into_iter()
            .flatten()
    }
}

/// The frames of a run: read in order (decoded ahead on a thread of their own, or inline), or
/// replayed at their timestamps as a live camera delivers them (`realtime`), dropping what
/// arrives while the run is busy.
enum Feed<'a> {
    /// Decoded ahead on their own thread (`read.ahead_frames`).
    Ahead(ReadAhead),
    InOrder {
        seq: &'a dyn Sequence,
        next: usize,
        n: usize,
    },
    Replay(ReplayCamera),
}

impl<'a> Feed<'a> {
    fn start(
        o: &RunOptions,
        seq: &'a dyn Sequence,
        n: usize,
        tree: &SettingsTree,
        reader: Option<ReadAhead>,
    ) -> Result<Self, RunError> {
        Ok(if let Some(reader) = reader {
            Feed::Ahead(reader)
        } else if o.realtime {
            let preload = tree.realtime.preload_mib.saturating_mul(1024 * 1024);
            let rate = Some(tree.realtime.rate_hz).filter(|r| r.is_finite() && *r > 0.0);
            Feed::Replay(ReplayCamera::start(open_sequence(o)?, n, preload, rate))
        } else {
            Feed::InOrder { seq, next: 0, n }
        })
    }

    /// The next frame, `None` at the end or once the stop flag is set.
    fn next(&mut self, o: &RunOptions) -> Option<Arrival> {
        if o.stop.is_some_and(|s| s.load(Ordering::SeqCst)) {
            tracing::warn!("interrupted: finishing the map and the trajectory files");
            return None;
        }
        match self {
            Feed::Replay(camera) => camera.next(),
            Feed::Ahead(reader) => reader.next(),
            Feed::InOrder { seq, next, n } if *next < *n => {
                *next += 1;
                Some((*next - 1, seq.frame(*next - 1), Instant::now()))
            }
            Feed::InOrder { .. } => None,
        }
    }

    /// A frame the run is done with: a reader frees it on its own thread.
    fn done_with(&self, frame: Frame) {
        if let Feed::Ahead(reader) = self {
            reader.done_with(frame);
        }
    }

    fn is_replay(&self) -> bool {
        matches!(self, Feed::Replay(_))
    }

    /// Frames the replay dropped (none in order).
    fn dropped(&self) -> usize {
        match self {
            Feed::Replay(camera) => camera.dropped,
            Feed::Ahead(_) | Feed::InOrder { .. } => 0,
        }
    }
}

/// What the run counts as frames go by.
struct Tally {
    culled: Vec<usize>,
    culled_matched: Vec<usize>,
    times: Vec<FrameTimings>,
    /// Per frame read in order: how long the run waited for it (decoding, unless read ahead).
    reading_ms: Vec<f64>,
    tracked: usize,
    relocalisations: usize,
    new_maps: usize,
    first_relocalisation: Option<usize>,
    /// With a replay at camera rate: time and latency per frame, frames dropped.
    realtime: Option<RealtimeReport>,
    depth_scale_checked: bool,
    // For a run that tracks nothing: what the frames offered.
    frames_read: usize,
    frames_with_depth: usize,
    most_keypoints: usize,
}

impl Tally {
    fn new(n: usize, replay: bool) -> Self {
        Self {
            culled: Vec::with_capacity(n.min(1 << 16)),
            culled_matched: Vec::with_capacity(n.min(1 << 16)),
            times: Vec::with_capacity(n.min(1 << 16)),
            reading_ms: Vec::with_capacity(n.min(1 << 16)),
            tracked: 0,
            relocalisations: 0,
            new_maps: 0,
            first_relocalisation: None,
            realtime: replay.then(RealtimeReport::default),
            depth_scale_checked: false,
            frames_read: 0,
            frames_with_depth: 0,
            most_keypoints: 0,
        }
    }

    /// A frame read, before tracking.
    fn read(&mut self, frame: &Frame, depth_factor: f64) {
        self.frames_read += 1;
        self.frames_with_depth += usize::from(frame.depth.is_some() || frame.right.is_some());
        if let (false, Some(depth)) = (self.depth_scale_checked, &frame.depth) {
            // The first frame with depth: a wrong factor scales the whole trajectory silently.
            self.depth_scale_checked = true;
            if let Some(w) = stillpoint_datasets::depth_scale_warning(depth, depth_factor) {
                tracing::warn!("frame {}: {w}", frame.index);
            }
        }
    }

    /// What tracking made of it; `started` when tracking began, `arrival` when the frame came.
    fn tracked(&mut self, r: &FrameResult, started: Instant, arrival: Instant) {
        if let Some(realtime) = self.realtime.as_mut() {
            let (processing_ms, latency_ms) = (ms_since(started), ms_since(arrival));
            realtime.frames_processed += 1;
            realtime.processing_ms.push(processing_ms);
            realtime.latency_ms.push(latency_ms);
            tracing::debug!(
                frame = r.index,
                processing_ms,
                latency_ms,
                geometry_ms = r.timings.geometry_ms,
                orb_ms = r.timings.orb_ms,
                tracking_ms = r.timings.tracking_ms,
                map_wait_ms = r.timings.map_wait_ms,
                keyframe = r.new_keyframe,
                "realtime frame"
            );
        }
        let culled = r.culled();
        self.most_keypoints = self.most_keypoints.max(r.keypoints.len() - culled);
        self.culled.push(culled);
        let culled_matched = r.culled_matched();
        self.culled_matched.push(culled_matched);
        tracing::debug!(
            frame = r.index,
            state = ?r.state,
            keypoints = r.keypoints.len() - culled,
            culled,
            culled_matched,
            inliers = r.inliers,
            keyframe = r.new_keyframe,
            "tracked"
        );
        self.relocalisations += r.relocalised as usize;
        if r.relocalised && self.first_relocalisation.is_none() {
            self.first_relocalisation = Some(self.culled.len() - 1);
        }
        self.new_maps += r.new_map as usize;
        // Earlier frames a new monocular map took in count too.
        self.tracked += r.poses_in_time_order().count();
        self.times.push(r.timings);
    }

    /// Per-frame times of each stage (ms).
    fn stage_times(&self, detector: bool, mapping_thread: bool) -> Vec<(&'static str, Vec<f64>)> {
        let pick = |f: fn(&FrameTimings) -> f64| self.times.iter().map(f).collect::<Vec<f64>>();
        let mut timings = vec![];
        if !self.reading_ms.is_empty() {
            timings.push(("reading", self.reading_ms.clone()));
        }
        if detector {
            timings.push(("semantic", pick(|t| t.semantic_ms)));
            timings.push(("geometry", pick(|t| t.geometry_ms)));
        }
        timings.push(("orb", pick(|t| t.orb_ms)));
        timings.push(("tracking", pick(|t| t.tracking_ms)));
        if mapping_thread {
            // Only a mapping thread can hold the map while a frame waits.
            timings.push(("tracking: waiting for the map", pick(|t| t.map_wait_ms)));
        }
        timings
    }

    /// Why a run tracked nothing: features, depth, initialisation.
    fn untracked_reason(
        &self,
        o: &RunOptions,
        ds: &stillpoint_datasets::Settings,
        slam: &SlamSettings,
    ) -> String {
        let most_keypoints = self.most_keypoints;
        let frames_read = self.frames_read;
        let culled_mean =
            self.culled.iter().sum::<usize>() as f64 / self.culled.len().max(1) as f64;
        if frames_read == 0 {
            "no frame could be read".to_string()
        } else if let Some(p) = &o.load_map {
            format!(
                "no frame relocalised in the map of {} (another place, or too few matches)",
                p.display()
            )
        } else if ds.sensor != Sensor::Mono && self.frames_with_depth == 0 {
            format!(
                "none of the {frames_read} frames had depth (an RGB-D map starts from depth: \
                 check depth.txt and the depth images)"
            )
        } else if most_keypoints < slam.init_min_keypoints {
            format!(
                "the most keypoints a frame kept was {most_keypoints}; a map starts with \
                 {} (slam.init_min_keypoints; plain or dark images, or the front-end culled them)",
                slam.init_min_keypoints
            )
        } else if ds.sensor == Sensor::Mono {
            // Monocular has no depth: its map starts from two views with parallax.
            format!(
                "the monocular map never started: no two frames gave {} matches with {}° of \
                 parallax (slam.mono_init); the camera must move, not only turn. Up to \
                 {most_keypoints} keypoints a frame were kept; the front-end culled \
                 {culled_mean:.0} a frame",
                slam.mono_init.min_matches, slam.mono_init.min_parallax_deg
            )
        } else {
            format!(
                "the map never started: up to {most_keypoints} keypoints a frame, but fewer than \
                 {} with depth, or spread over fewer than {} of the 16 image cells",
                slam.init_min_with_depth, slam.init_min_cells_with_depth
            )
        }
    }
}
