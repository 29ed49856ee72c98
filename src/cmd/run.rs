//! `stillpoint run`: SLAM over a dataset (RGB-D, stereo or monocular, as the dataset provides),
//! with the dynamic front-end (paper figure 2) on every frame unless `--no-dynamic`. The per-frame trajectory is written as it goes (TUM), the
//! keyframe trajectory at the end, then a timing table like the paper's table 6. The run itself
//! is `stillpoint_run::run_sequence`; this module parses its arguments and prints its summary.

use std::path::PathBuf;

use anyhow::bail;
use stillpoint_datasets::DatasetKind;
use stillpoint_datasets::mcap::McapTopics;
use stillpoint_eval::{ScoredRun, stats};
use stillpoint_run::{Event, Media, Overrides, RealtimeReport, RunOptions, RunSummary};
use stillpoint_trajectory::Alignment;

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
    /// Write a picture of each frame into this folder (`000042.png`): keypoints matched green,
    /// kept yellow, culled red; objects boxed red when moving, blue when static.
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    /// Write the map's points at the end as a PLY point cloud (x y z, metres, and how many
    /// keyframes see each point).
    #[arg(long)]
    pub map_cloud: Option<PathBuf>,
    /// RGB-D and stereo: write a dense cloud of the static scene (keyframe depth, or stereo
    /// depth matched densely, fused in 1 cm voxels, the movers' pixels left out; `--set
    /// dense.voxel_m=...`) as PLY.
    #[arg(long)]
    pub dense_cloud: Option<PathBuf>,
    /// Record the run as an MCAP file for Foxglove: each frame's image with its keypoints and
    /// boxes, the camera's pose and path, the map's points and keyframes, the culled keypoints
    /// lifted into 3D (`[record]` settings: `--set record.image=png`).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// A ROS recording to run on instead of a folder: ROS 2 (`.mcap`, or the `ros2 bag` folder
    /// holding one) or ROS 1 (`.bag`); colour from `--rgb-topic`, depth from `--depth-topic`
    /// or a stereo pair's right images from `--right-topic` (monocular without), the camera
    /// from `--settings` or the recording's CameraInfo.
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
    /// The right images of a rectified stereo pair whose left images are --rgb-topic, e.g.
    /// /stereo/right/image_rect; without --settings the baseline comes from the right
    /// CameraInfo's projection (P[3] = -fx * baseline, as stereo_image_proc publishes it).
    #[arg(long, requires = "bag", conflicts_with = "depth_topic")]
    pub right_topic: Option<String>,
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
    /// Everything on one thread, frame after frame: local mapping inline after each keyframe
    /// (already so for a recording unless `--realtime`) and each frame read when its turn comes:
    /// `--set slam.local_mapping_thread=false --set read.ahead_frames=0`.
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
    /// essential-graph correction): `--set slam.loop_closing.enabled=false`.
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
    #[command(flatten)]
    pub maps: MapArgs,
    /// Print a JSON summary on stdout instead of the tables.
    #[arg(long)]
    pub json: bool,
}

/// Saved maps in and out (`run` and `ros2` share them).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct MapArgs {
    /// Save the final map (keyframes, points, covisibility graph, spanning tree, loop edges,
    /// vocabulary) to this file: versioned, checksummed, written atomically (also on Ctrl-C or
    /// SIGTERM).
    #[arg(long, conflicts_with = "localize")]
    pub save_map: Option<PathBuf>,
    /// Start in a map saved by --save-map: relocalise in it, then map on in it (new keyframes
    /// are added; --save-map writes the grown map). Same camera and vocabulary only.
    #[arg(long)]
    pub load_map: Option<PathBuf>,
    /// With --load-map: only localise (relocalise, then track against the map without
    /// changing it: no keyframes, points, bundle adjustment or loop closing).
    #[arg(long, requires = "load_map")]
    pub localize: bool,
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

/// A progress bar on stderr over a run's frames, cleared when the frames are done.
#[derive(Default)]
pub struct ProgressBar {
    bar: Option<indicatif::ProgressBar>,
}

impl ProgressBar {
    /// Show `event` (`run_sequence`'s progress callback).
    pub fn show(&mut self, event: Event) {
        match event {
            Event::Next { index, frames } => {
                let bar = self.bar.get_or_insert_with(|| {
                    // A live source has no known length (usize::MAX frames).
                    let b = if frames == usize::MAX {
                        indicatif::ProgressBar::no_length()
                    } else {
                        indicatif::ProgressBar::new(frames as u64)
                    };
                    b.set_style(
                        indicatif::ProgressStyle::with_template(
                            "{spinner} {bar:40} {pos}/{len} frames {elapsed} ({eta} left) {msg}",
                        )
                        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
                    );
                    b
                });
                bar.set_position(index as u64 + 1);
            }
            Event::Tracked { result, keyframes } => {
                if let Some(bar) = &self.bar {
                    bar.set_message(format!("{:?}, {keyframes} kf", result.state));
                }
            }
            Event::Finishing => {
                if let Some(bar) = self.bar.take() {
                    bar.finish_and_clear();
                }
            }
        }
    }
}

/// Loop closing in the JSON summary: counts, and per loop the frames and how far apart the two
/// keyframes truly are (ground truth), which tells a true revisit from a false loop.
fn loops_json(scored: &ScoredRun) -> serde_json::Value {
    let s = &scored.run;
    let Some(l) = &s.loops else {
        return serde_json::Value::Null;
    };
    let events: Vec<serde_json::Value> = l
        .loops
        .iter()
        .map(|e| {
            let truth = scored.ground_truth.as_ref().and_then(|gt| {
                stillpoint_eval::accuracy::true_separation(gt, e.timestamp, e.loop_timestamp)
            });
            serde_json::json!({
                "frame": e.frame_index, "loop_frame": e.loop_frame_index,
                "keyframe": e.keyframe, "loop_keyframe": e.loop_keyframe,
                "ransac_inliers": e.ransac_inliers, "refined_inliers": e.refined_inliers,
                "loop_matches": e.loop_matches,
                "correction_m": e.correction_m, "correction_deg": e.correction_deg,
                "correction_scale": e.correction_scale,
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

pub fn summary_json(scored: &ScoredRun) -> serde_json::Value {
    let s = &scored.run;
    let acc = scored.accuracy();
    let ate_keyframes = scored.keyframe_ate();
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
    let (mm, mmed, mp90) = s.culled_matched_stats();
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
        "maps": {
            "made": s.maps.made,
            "merged": s.maps.merged,
            "main": s.maps.main,
            "frames": s.maps.frames.iter().map(|(map, frames)| serde_json::json!({"map": map, "frames": frames})).collect::<Vec<_>>(),
        },
        "culled_per_frame": {"mean": cm, "median": cmed, "p90": cp90},
        "culled_matched_per_frame": {"mean": mm, "median": mmed, "p90": mp90},
        "ate": acc.as_ref().map(|(a, _)| serde_json::json!({
            "align": scored.alignment(), "scale": a.alignment.scale,
            "rmse": a.stats.rmse, "mean": a.stats.mean, "median": a.stats.median,
            "std": a.stats.std, "max": a.stats.max, "pairs": a.stats.count,
            "scale_drift": stillpoint_trajectory::scale_along_path(a, stillpoint_trajectory::SCALE_PIECES).map(|s| s.drift)})),
        "rpe_1s": acc.as_ref().and_then(|(_, r)| r.as_ref()).map(|r| serde_json::json!({
            "trans_rmse": r.translation.rmse, "trans_std": r.translation.std,
            "rot_rmse_deg": r.rotation_deg.rmse})),
        "timing": timing,
        "wall_s": s.wall_s,
        "frames_per_second": (s.wall_s > 0.0).then(|| s.frames as f64 / s.wall_s),
        // The process's peak so far: for `run` (one run a process) the run's own; `demo`'s two
        // runs share one process, so both report the larger.
        "peak_memory_mib": stillpoint_core::memory_mib().1,
        "moving_keypoints_kept_per_frame": scored.moving_kept_stats().map(|(m, med, p90)| {
            serde_json::json!({"mean": m, "median": med, "p90": p90})
        }),
        "static_keypoints_culled_share": scored.static_culled_stats().map(|(m, med, p90)| {
            serde_json::json!({"mean": m, "median": med, "p90": p90})
        }),
        "moving_map_points": scored.moving_map_points.map(|m| m.lying),
        "moving_map_points_seen": scored.moving_map_points.map(|m| m.seen),
        "first_relocalisation": s.first_relocalisation,
        "map_file": map_files_json(s),
        "dense_points": s.dense.map(|d| d.points),
        "dense_points_on_movers": s.dense.and_then(|d| d.on_movers),
        "record": s.record.as_ref().map(|r| serde_json::json!({"bytes": r.bytes, "messages": r.messages})),
        "ate_keyframes": ate_keyframes.map(|a| serde_json::json!({"rmse": a.stats.rmse, "pairs": a.stats.count})),
        "loop_closing": loops_json(scored),
        "realtime": s.realtime.as_ref().map(|r| realtime_json(r, acc.as_ref().map(|(a, _)| a.stats.rmse))),
    })
}

/// The map loaded and saved (`--load-map`, `--save-map`) in the JSON summary.
fn map_files_json(s: &RunSummary) -> serde_json::Value {
    let one = |r: &stillpoint_run::MapFileReport| {
        serde_json::json!({"keyframes": r.keyframes, "map_points": r.map_points,
            "bytes": r.bytes, "ms": r.ms})
    };
    serde_json::json!({
        "loaded": s.map_files.loaded.as_ref().map(one),
        "saved": s.map_files.saved.as_ref().map(one),
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

pub fn print_summary(scored: &ScoredRun) {
    let s = &scored.run;
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
    if s.wall_s > 0.0 {
        let peak = stillpoint_core::memory_mib()
            .1
            .map_or(String::new(), |m| format!(", peak memory {m:.0} MiB"));
        println!(
            "{} frames in {:.1} s ({:.1} frames a second{peak})",
            s.frames,
            s.wall_s,
            s.frames as f64 / s.wall_s
        );
    }
    if s.maps.made > 1 {
        let frames: Vec<String> = s
            .maps
            .frames
            .iter()
            .map(|(map, n)| format!("map {map}: {n}"))
            .collect();
        println!(
            "maps: {} made, {} merged; frames per map: {} (the trajectory holds map {}'s)",
            s.maps.made,
            s.maps.merged,
            frames.join(", "),
            s.maps.main
        );
    }
    if let Some(l) = &s.map_files.loaded {
        println!(
            "map loaded: {} keyframes, {} map points ({} bytes, {:.1} ms); first relocalised at frame {}",
            l.keyframes,
            l.map_points,
            l.bytes,
            l.ms,
            s.first_relocalisation
                .map_or("-".to_string(), |f| f.to_string())
        );
    }
    if let Some(m) = &s.map_files.saved {
        println!(
            "map saved: {} keyframes, {} map points ({} bytes, {:.1} ms)",
            m.keyframes, m.map_points, m.bytes, m.ms
        );
    }
    if let Some((a, r)) = scored.accuracy() {
        print!(
            "ATE RMSE {:.4} m (S.D. {:.4}, {} pairs{})",
            a.stats.rmse,
            a.stats.std,
            a.stats.count,
            if scored.alignment() == Alignment::Sim3 {
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
    if s.culled_matched_per_frame.iter().any(|&m| m > 0) {
        let (m, med, p90) = s.culled_matched_stats();
        println!(
            "{:<30} {m:>9.1} {med:>9.1} {p90:>9.1}",
            "  of those matched to the map"
        );
    }
}

/// The flags that are shorthands for settings, as `--set`s laid before the user's own (which
/// win): the run's settings tree, and `stillpoint settings`, see them as settings.
fn shorthands(args: &Args) -> impl Iterator<Item = String> + use<> {
    [
        (args.sequential, "slam.local_mapping_thread=false"),
        (args.sequential, "read.ahead_frames=0"),
        (args.no_loop_closing, "slam.loop_closing.enabled=false"),
    ]
    .into_iter()
    .filter(|(on, _)| *on)
    .map(|(_, set)| set.to_string())
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
        right: args.right_topic.clone(),
        camera_info: args.camera_info_topic.clone(),
    });
    let o = RunOptions {
        dataset,
        kind,
        settings: args.settings.clone(),
        out: Some(args.out.clone()),
        detector: (!args.no_dynamic).then(|| args.detector.clone()),
        realtime: args.realtime,
        frames: args.frames,
        model: args.model.clone(),
        paper_cull: args.paper_cull,
        overlay: args.overlay.clone(),
        map_cloud: args.map_cloud.clone(),
        dense_cloud: args.dense_cloud.clone(),
        record: args.record.clone(),
        overrides: Overrides {
            config: args.layers.config.clone(),
            sets: shorthands(&args).chain(args.layers.sets.clone()).collect(),
            vocabulary: args.vocabulary.clone(),
            recording,
            media,
        },
        stop: Some(crate::interrupt_flag()),
        load_map: args.maps.load_map.clone(),
        localize: args.maps.localize,
        save_map: args.maps.save_map.clone(),
    };
    let mut bar = ProgressBar::default();
    let scored = stillpoint_eval::run_scored(&o, &mut |e| bar.show(e))?;
    tracing::info!(
        "trajectory written to {} (keyframes: {})",
        args.out.display(),
        stillpoint_run::keyframe_path(&args.out).display()
    );
    if args.json {
        println!("{}", summary_json(&scored));
    } else {
        print_summary(&scored);
    }
    let s = &scored.run;
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

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        run: Args,
    }

    /// `--sequential` and `--no-loop-closing` are settings: laid before `--set`, which wins.
    #[test]
    fn flags_that_are_settings_become_sets_before_the_users() {
        let cli = Cli::parse_from([
            "run",
            "--dataset",
            "d",
            "--sequential",
            "--no-loop-closing",
            "--set",
            "slam.local_mapping_thread=true",
        ]);
        let sets: Vec<String> = shorthands(&cli.run)
            .chain(cli.run.layers.sets.clone())
            .collect();
        assert_eq!(
            sets,
            [
                "slam.local_mapping_thread=false",
                "read.ahead_frames=0",
                "slam.loop_closing.enabled=false",
                "slam.local_mapping_thread=true",
            ]
        );
        let plain = Cli::parse_from(["run", "--dataset", "d"]);
        assert_eq!(shorthands(&plain.run).count(), 0);
    }
}
