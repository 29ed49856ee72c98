//! The run itself: settings, detector and front-end, the frame loop, the files, the summary.

use std::path::Path;
use std::sync::atomic::Ordering;
use std::time::Instant;

use stillpoint_core::ms_since;

use stillpoint_datasets::{Sensor, Sequence};
use stillpoint_detect::GtDetectorParams;
use stillpoint_frontend::{DynamicFrontEnd, FrontEnd, FrontEndSettings};
use stillpoint_pipeline::{FrameResult, FrameTimings, Layered, Pipeline, SettingsTree};
use stillpoint_trajectory::TumWriter;

use crate::output::{keyframe_path, lock_output};
use crate::replay::{RealtimeReport, ReplayCamera};
use crate::{
    DenseReport, MapFileReport, MapFilesReport, Media, Overrides, RunError, RunOptions, RunSummary,
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

/// Run SLAM over a sequence. Frames that cannot be read are logged and skipped. `progress`
/// hears of each frame ([`Event`]).
pub fn run_sequence(
    o: &RunOptions,
    progress: &mut dyn FnMut(Event),
) -> Result<RunSummary, RunError> {
    let seq = open_sequence(o)?;
    let ds = seq.settings().clone();
    let layers = settings_layers(&ds, o.settings.as_deref(), o.paper_cull, &o.overrides)?;
    let tree = layers.tree;
    let mut pipeline_settings = tree.pipeline();
    // A recording is not a race: mapped inline, its trajectory is the same however busy the
    // machine is (on its own thread, a mapper that falls behind leaves tracking without the
    // points of the last keyframes, and a monocular run then loses them). A camera and
    // `--realtime` cannot wait for the mapper: they map on its own thread unless the settings
    // say otherwise.
    // A live source has no known end (len usize::MAX): frames are counted as they come.
    let live = seq.len() == usize::MAX;
    if !layers.sources.contains_key("slam.local_mapping_thread") {
        pipeline_settings.slam.local_mapping_thread = live || o.realtime;
    }
    let mapping_thread = pipeline_settings.slam.local_mapping_thread;
    let vocabulary = o
        .overrides
        .vocabulary
        .as_deref()
        .map(read_vocabulary)
        .transpose()?;
    if o.localize && o.load_map.is_none() {
        return Err(RunError::Refused(
            "--localize needs a map to localise in (--load-map FILE)".into(),
        ));
    }
    let mut map_files = MapFilesReport::default();
    // Read and checked before the detector opens: a wrong map fails at once.
    let loaded_map = match &o.load_map {
        Some(path) => {
            let t0 = Instant::now();
            let map_error = |source| RunError::MapFile {
                path: path.clone(),
                source,
            };
            let bytes = std::fs::read(path).map_err(|e| map_error(e.into()))?;
            let file = stillpoint_slam::map_file::decode(&bytes).map_err(map_error)?;
            file.check_settings(&pipeline_settings.slam)
                .map_err(map_error)?;
            if let Some(v) = &vocabulary {
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
            map_files.loaded = Some(report);
            Some((path.clone(), file))
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
            .map_err(|source| RunError::Detector {
                context: format!("opening the {name} detector"),
                source,
            })?;
            detector_desc = match detector.input_size() {
                Some((h, w)) => format!("{} {w}x{h}", detector.name()),
                None => detector.name().to_string(),
            };
            let front = DynamicFrontEnd::new(detector, tree.front_end.clone());
            let front = if tree.front_end.detector_in_background || o.realtime {
                front
                    .detect_in_background()
                    .map_err(|source| RunError::Detector {
                        context: format!("starting the {name} detector's thread"),
                        source,
                    })?
            } else {
                front
            };
            Some(Box::new(front) as Box<dyn FrontEnd>)
        }
    };
    let detector_name = detector_desc;
    if o.frames == Some(0) {
        return Err(RunError::Refused(
            "--frames 0: nothing to run (give at least 1, or leave it out for every frame)".into(),
        ));
    }
    let n = o.frames.map_or(seq.len(), |f| f.min(seq.len()));
    if n == 0 {
        return Err(RunError::Refused(format!(
            "{}: the sequence has no frames",
            o.dataset.display()
        )));
    }
    let _lock = o.out.as_deref().map(lock_output).transpose()?;
    if let Some(dir) = &o.overlay {
        std::fs::create_dir_all(dir).map_err(|source| RunError::Io {
            context: format!("creating {}", dir.display()),
            source,
        })?;
    }
    let mut recorder = o
        .record
        .as_deref()
        .map(|p| crate::record::Recorder::create(p, &tree.record))
        .transpose()?;
    let camera_model = pipeline_settings.slam.camera;
    let mut writer = match &o.out {
        Some(p) => Some(TumWriter::create(p).map_err(|source| RunError::Trajectory {
            context: format!("creating {}", p.display()),
            source,
        })?),
        None => None,
    };
    let mut camera = if o.realtime {
        Some(ReplayCamera::start(
            open_sequence(o)?,
            n,
            tree.realtime.preload_mib.saturating_mul(1024 * 1024),
        ))
    } else {
        None
    };
    let mut realtime = RealtimeReport::default();
    let pipeline_settings_init = (
        pipeline_settings.slam.init_min_keypoints,
        pipeline_settings.slam.init_min_with_depth,
        pipeline_settings.slam.init_min_cells_with_depth,
    );
    let mono_init = pipeline_settings.slam.mono_init.clone();
    let mut dense = o.dense_cloud.as_ref().map(|_| {
        stillpoint_pipeline::dense::DenseFusion::new(
            tree.dense.clone(),
            pipeline_settings.slam.camera,
        )
    });
    let map_loaded = loaded_map.is_some();
    let mut pipeline = match loaded_map {
        Some((path, file)) => {
            let mode = if o.localize {
                stillpoint_slam::LoadedMapMode::Localize
            } else {
                stillpoint_slam::LoadedMapMode::Extend
            };
            Pipeline::with_map(pipeline_settings, front, vocabulary, file, mode)
                .map_err(|source| RunError::MapFile { path, source })?
        }
        None => Pipeline::new(pipeline_settings, front, vocabulary),
    };
    let mut first_relocalisation = None;
    let mut times: Vec<FrameTimings> = Vec::with_capacity(n.min(1 << 16));
    let mut record_ms = Vec::new();
    let mut written: Option<f64> = None;
    let mut culled = Vec::with_capacity(n.min(1 << 16));
    let (mut tracked, mut relocs, mut new_maps) = (0, 0, 0);
    let has_masks = o.dataset.join("mask").is_dir();
    let mut moving_kept = Vec::new();
    let mut static_culled = Vec::new();
    let mut depth_scale_checked = false;
    // For a run that tracks nothing: what the frames offered.
    let (mut frames_read, mut frames_with_depth, mut most_keypoints) = (0usize, 0usize, 0usize);
    let mut next_index = 0;
    let mut ended = None;
    loop {
        if o.stop.is_some_and(|s| s.load(Ordering::SeqCst)) {
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
            .map_err(|source| RunError::Pipeline {
                context: format!("{}", o.dataset.display()),
                source,
            })?;
        if camera.is_some() {
            let (processing_ms, latency_ms) = (ms_since(started), ms_since(arrival));
            realtime.frames_processed += 1;
            realtime.processing_ms.push(processing_ms);
            realtime.latency_ms.push(latency_ms);
            tracing::debug!(
                frame = i,
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
        let n_culled = r.culled();
        most_keypoints = most_keypoints.max(r.keypoints.len() - n_culled);
        culled.push(n_culled);
        // The generator's mask, read once for both of its uses.
        let truth_mask = has_masks
            .then(|| stillpoint_eval::movers::moving_mask(&o.dataset, frame.timestamp))
            .flatten();
        let kept_on_movers = truth_mask
            .as_ref()
            .map(|m| stillpoint_eval::movers::moving_keypoints_kept(m, &r.keypoints, &r.dynamic));
        if has_masks {
            moving_kept.push(kept_on_movers.unwrap_or(0));
        }
        if let Some(share) = truth_mask.as_ref().and_then(|m| {
            stillpoint_eval::movers::static_keypoints_culled_share(m, &r.keypoints, &r.dynamic)
        }) {
            static_culled.push(share);
        }
        tracing::debug!(
            frame = i,
            state = ?r.state,
            keypoints = r.keypoints.len() - n_culled,
            culled = n_culled,
            inliers = r.inliers,
            keyframe = r.new_keyframe,
            // Synthetic sequences: kept keypoints and pose inliers on the generator's movers.
            kept_on_movers,
            inliers_on_movers = truth_mask.as_ref().map(|m| {
                stillpoint_eval::movers::moving_keypoints_matched(m, &r.keypoints, &r.matched)
            }),
            "tracked"
        );
        relocs += r.relocalised as usize;
        if r.relocalised && first_relocalisation.is_none() {
            first_relocalisation = Some(culled.len() - 1);
        }
        new_maps += r.new_map as usize;
        // Earlier frames a new monocular map took in come first, in time order.
        for (index, t, p) in r.poses_in_time_order() {
            tracked += 1;
            if written.is_none_or(|l| t > l) {
                written = Some(t);
                if let Some(w) = writer.as_mut() {
                    w.write(t, &p).map_err(|source| RunError::Trajectory {
                        context: format!("writing frame {index}"),
                        source,
                    })?;
                }
            }
        }
        if let (Some(d), Some(depth), true) = (dense.as_mut(), &frame.depth, r.new_keyframe) {
            // The pixels of movers and of people (still or not) stay out of the static cloud.
            let skip = r
                .objects
                .movable
                .mask(Some(depth), depth.width, depth.height);
            d.add_keyframe(
                frame.timestamp,
                depth,
                frame.rgb.as_ref(),
                skip.as_ref(),
                truth_mask.as_ref(),
            );
        }
        if let Some(dir) = &o.overlay {
            let img = crate::overlay::draw_overlay(&frame, &r);
            let path = crate::overlay::overlay_path(dir, frame.index);
            stillpoint_image::write_rgb(&path, &img).map_err(|e| RunError::Io {
                context: format!("writing {}", path.display()),
                source: std::io::Error::other(e.to_string()),
            })?;
        }
        if let Some(rec) = recorder.as_mut() {
            let t0 = Instant::now();
            rec.frame(&crate::record::FrameRecord {
                frame: &frame,
                result: &r,
                camera: &camera_model,
            })?;
            if r.new_keyframe {
                let map = pipeline.system().map();
                if let Ok(map) = map.lock() {
                    rec.keyframe(&map)?;
                }
            }
            record_ms.push(ms_since(t0));
        }
        progress(Event::Tracked {
            result: &r,
            keyframes: pipeline.system().keyframe_count(),
        });
        times.push(r.timings);
    }
    progress(Event::Finishing);
    let fin = pipeline.finish().map_err(|source| RunError::Pipeline {
        context: "local mapping".into(),
        source,
    })?;
    // The file written as we went (tracking's poses: what a crash leaves) is replaced by the
    // frames following their keyframes as bundle adjustment and loop closing left them.
    if let Some(p) = &o.out {
        stillpoint_trajectory::write_tum(p, &fin.trajectory).map_err(|source| {
            RunError::Trajectory {
                context: format!("rewriting {}", p.display()),
                source,
            }
        })?;
        if fin.loop_closed {
            tracing::info!("loop closed: trajectory rebuilt through the keyframes");
        }
    }
    if let Some(p) = &o.out {
        let kp = keyframe_path(p);
        stillpoint_trajectory::write_tum(&kp, &fin.keyframe_trajectory).map_err(|source| {
            RunError::Trajectory {
                context: format!("writing {}", kp.display()),
                source,
            }
        })?;
    }
    let ground_truth = seq.ground_truth().and_then(|p| {
        stillpoint_eval::read_ground_truth(seq.as_ref(), &p)
            .map_err(|e| tracing::warn!("ground truth unreadable: {}", crate::error_chain(&e)))
            .ok()
    });
    let mut dense_report = None;
    if let (Some(path), Some(d)) = (&o.dense_cloud, &dense) {
        let poses: std::collections::HashMap<u64, stillpoint_geometry::Se3> = fin
            .trajectory
            .stamps
            .iter()
            .zip(&fin.trajectory.poses)
            .map(|(t, p)| (t.to_bits(), *p))
            .collect();
        let points = d.fuse(|t| poses.get(&t.to_bits()).copied());
        let file = std::fs::File::create(path).map_err(|source| RunError::Io {
            context: format!("writing {}", path.display()),
            source,
        })?;
        stillpoint_pipeline::dense::write_dense_ply(&points, std::io::BufWriter::new(file))
            .map_err(|source| RunError::Io {
                context: format!("writing {}", path.display()),
                source,
            })?;
        let on_movers = has_masks.then(|| points.iter().filter(|p| p.on_mover).count());
        tracing::info!(
            "{} dense points from {} keyframes written to {}{}",
            points.len(),
            d.keyframes(),
            path.display(),
            on_movers.map_or(String::new(), |m| format!(" ({m} on movers)"))
        );
        dense_report = Some(DenseReport {
            points: points.len(),
            on_movers,
        });
    }
    if let Some(path) = &o.map_cloud {
        let io = |source| RunError::Io {
            context: format!("writing {}", path.display()),
            source,
        };
        let file = std::fs::File::create(path).map_err(io)?;
        let map = fin.system.map();
        let written = match map.lock() {
            Ok(map) => {
                stillpoint_slam::io::write_map_points_ply(&map, std::io::BufWriter::new(file))
                    .map_err(io)?
            }
            Err(_) => 0,
        };
        tracing::info!("{written} map points written to {}", path.display());
    }
    if let Some(path) = &o.save_map {
        let t0 = Instant::now();
        let file = fin.system.map_file();
        let bytes =
            stillpoint_slam::map_file::save(path, &file).map_err(|source| RunError::MapFile {
                path: path.clone(),
                source: source.into(),
            })?;
        let report = MapFileReport {
            keyframes: file.map.keyframes.len(),
            map_points: file.map.points.len(),
            bytes,
            ms: ms_since(t0),
        };
        tracing::info!(
            "map saved to {}: {} keyframes, {} map points, vocabulary {}, {} bytes in {:.1} ms",
            path.display(),
            report.keyframes,
            report.map_points,
            file.vocabulary
                .as_ref()
                .map_or("none".to_string(), |v| format!("{} words", v.words())),
            report.bytes,
            report.ms
        );
        map_files.saved = Some(report);
    }
    let record = match recorder {
        Some(rec) => {
            let map = fin.system.map();
            let map = map.lock().ok();
            let report = rec.finish(map.as_deref(), &fin.trajectory)?;
            if let Some(p) = &o.record {
                tracing::info!(
                    "recording written to {} ({:.1} MB, {} messages)",
                    p.display(),
                    report.bytes as f64 / 1e6,
                    report.messages.values().sum::<usize>()
                );
            }
            Some(report)
        }
        None => None,
    };
    // A loaded map's keyframes carry another sequence's timestamps: no masks to judge them by.
    let moving_map_points = (has_masks && !map_loaded).then(|| {
        fin.system.map().lock().map_or(Default::default(), |map| {
            stillpoint_eval::movers::moving_map_points(&map, |t| {
                stillpoint_eval::movers::moving_mask(&o.dataset, t)
            })
        })
    });
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
    if mapping_thread {
        // Only a mapping thread can hold the map while a frame waits.
        timings.push(("tracking: waiting for the map", pick(|t| t.map_wait_ms)));
    }
    let loops = fin.loops;
    timings.push(("local mapping (per keyframe)", fin.mapping_ms));
    if o.record.is_some() {
        timings.push(("recording", record_ms));
    }
    if let Some(l) = &loops {
        timings.push(("loop detection (per keyframe)", l.detection_ms.clone()));
        timings.push(("loop correction", l.correction_ms.clone()));
        timings.push(("global BA after a loop", l.global_ba_ms.clone()));
        timings.push(("vocabulary training", l.training_ms.clone()));
    }
    let culled_mean = culled.iter().sum::<usize>() as f64 / culled.len().max(1) as f64;
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
        static_culled_share_per_frame: has_masks.then_some(static_culled),
        moving_map_points,
        loops,
        realtime: camera.is_some().then_some(realtime),
        ended,
        dense: dense_report,
        first_relocalisation,
        map_files,
        record,
        untracked_reason: (tracked == 0).then(|| {
            let init = &pipeline_settings_init;
            if frames_read == 0 {
                "no frame could be read".to_string()
            } else if let Some(p) = &o.load_map {
                format!(
                    "no frame relocalised in the map of {} (another place, or too few matches)",
                    p.display()
                )
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
            } else if ds.sensor == Sensor::Mono {
                // Monocular has no depth: its map starts from two views with parallax.
                format!(
                    "the monocular map never started: no two frames gave {} matches with {}° of \
                     parallax (slam.mono_init); the camera must move, not only turn. Up to \
                     {most_keypoints} keypoints a frame were kept; the front-end culled \
                     {culled_mean:.0} a frame",
                    mono_init.min_matches, mono_init.min_parallax_deg
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
