//! `stillpoint ros2`: SLAM as a ROS 2 node over DDS (no ROS install): the camera's topics in,
//! odometry, `/tf`, the path, the map cloud, an annotated image and the tracking state out.
//! The flags are shorthands for the `[ros2]` settings; the node is `stillpoint_ros2::run_node`.

use std::path::PathBuf;

use super::run::{MapArgs, SettingsArgs};

#[derive(clap::Args)]
pub struct Args {
    /// rgbd, stereo or mono: `--set ros2.sensor=...`.
    #[arg(long)]
    pub sensor: Option<String>,
    /// The colour (left, only) image topic; a `/compressed` suffix reads CompressedImage:
    /// `--set ros2.image_topic=...` (default: a RealSense's /camera/camera/color/image_raw).
    #[arg(long)]
    pub image_topic: Option<String>,
    /// The depth topic, registered to the colour image: `--set ros2.depth_topic=...`.
    #[arg(long)]
    pub depth_topic: Option<String>,
    /// The right image of a rectified pair: `--set ros2.right_topic=...`.
    #[arg(long)]
    pub right_topic: Option<String>,
    /// The colour camera's CameraInfo (default: camera_info beside the image topic).
    #[arg(long)]
    pub camera_info_topic: Option<String>,
    /// Subscribe reliably (default: best effort, as sensor data is published).
    #[arg(long)]
    pub reliable: bool,
    /// Lock-step: every frame tracked in order, reliable, mapping and the detector inline; a
    /// peer that sends the next frame once /stillpoint/state answered gets `run --sequential`'s
    /// trajectory.
    #[arg(long)]
    pub sequential: bool,
    /// The camera from this ORB-SLAM YAML or stillpoint TOML file instead of CameraInfo.
    #[arg(long)]
    pub settings: Option<PathBuf>,
    /// Object detector: yolox or none.
    #[arg(long, default_value = "yolox")]
    pub detector: String,
    /// Turn the dynamic front-end off.
    #[arg(long)]
    pub no_dynamic: bool,
    /// YOLOX ONNX model.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// The trajectory (TUM), written as it goes and rewritten at the end.
    #[arg(long, default_value = "trajectory.txt")]
    pub out: PathBuf,
    #[command(flatten)]
    pub maps: MapArgs,
    #[command(flatten)]
    pub layers: SettingsArgs,
    /// Print a JSON summary on stdout at the end.
    #[arg(long)]
    pub json: bool,
}

/// The flags as `--set`s, laid before the user's own.
#[cfg(feature = "ros2")]
fn shorthands(a: &Args) -> Vec<String> {
    let mut sets = Vec::new();
    let mut put = |key: &str, v: &Option<String>| {
        if let Some(v) = v {
            sets.push(format!("ros2.{key}={v}"));
        }
    };
    put("sensor", &a.sensor);
    put("image_topic", &a.image_topic);
    put("depth_topic", &a.depth_topic);
    put("right_topic", &a.right_topic);
    put("camera_info_topic", &a.camera_info_topic);
    if a.reliable {
        sets.push("ros2.reliable=true".into());
    }
    sets
}

#[cfg(not(feature = "ros2"))]
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!(
        "this stillpoint was built without ROS 2: cargo install --path . --features ros2 (or cargo build --release --features ros2)"
    )
}

#[cfg(feature = "ros2")]
pub fn run(args: Args) -> anyhow::Result<()> {
    use stillpoint_run::{Overrides, RunOptions};
    let mut sets = shorthands(&args);
    sets.extend(args.layers.sets.iter().cloned());
    let mut run = RunOptions::new(PathBuf::from("ros2"));
    run.settings = args.settings.clone();
    run.out = Some(args.out.clone());
    run.detector = (!args.no_dynamic).then(|| args.detector.clone());
    run.model = args.model.clone();
    run.overrides = Overrides {
        config: args.layers.config.clone(),
        sets,
        ..Overrides::default()
    };
    run.stop = Some(crate::interrupt_flag());
    run.load_map = args.maps.load_map.clone();
    run.localize = args.maps.localize;
    run.save_map = args.maps.save_map.clone();
    let node = stillpoint_ros2::NodeOptions {
        run,
        lock_step: args.sequential,
    };
    let s = stillpoint_ros2::run_node(&node)?;
    let mut ms = s.latencies.ms.clone();
    ms.sort_by(f64::total_cmp);
    let q = |p: f64| (!ms.is_empty()).then(|| ms[((ms.len() - 1) as f64 * p).round() as usize]);
    let processed = s.run.culled_per_frame.len();
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "sensor": s.run.sensor,
                "frames_received": s.latencies.received,
                "frames_processed": processed,
                "frames_dropped": s.latencies.received.saturating_sub(processed),
                "tracked": s.run.tracked,
                "keyframes": s.run.keyframes,
                "map_points": s.run.map_points,
                "latency_ms": {"p50": q(0.5), "p95": q(0.95), "max": ms.last()},
                "maps": {"made": s.run.maps.made, "merged": s.run.maps.merged},
            })
        );
    } else {
        println!(
            "frames: {} received, {processed} processed, {} tracked; latency p50 {:.1} ms, p95 {:.1} ms",
            s.latencies.received,
            s.run.tracked,
            q(0.5).unwrap_or(f64::NAN),
            q(0.95).unwrap_or(f64::NAN)
        );
    }
    Ok(())
}
