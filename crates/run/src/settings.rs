//! One settings tree for a whole run: the system's settings (`slam`, `orb`, `stereo`,
//! `front_end`) and the run's own tables (`detect`, `dense`, `record`, `realtime`, `read`), read from a
//! stillpoint TOML file over the defaults and overridden with `section.key=value` on the command
//! line ([`stillpoint_pipeline::settings::layered`]). Each value remembers where it came from, so
//! `stillpoint settings` can show it.
//!
//! The camera, frame rate, depth factor and ORB sizes start from the dataset's own settings
//! (an ORB-SLAM YAML or a synthetic sequence's `settings.toml`); everything else from the
//! crates' defaults.
//!
//! ```
//! use stillpoint_run::SettingsTree;
//! use stillpoint_datasets::{Sensor, Settings};
//! let camera = stillpoint_geometry::PinholeCamera::new(535.4, 539.2, 320.1, 247.6, 640, 480);
//! let ds = Settings::with_camera(Sensor::Rgbd, camera);
//! let tree = SettingsTree::from_dataset(&ds)
//!     .layered(&[], &["front_end.dynamic.judge.ata_ratio=0.5".into()])
//!     .unwrap();
//! assert_eq!(tree.tree.front_end.dynamic.judge.ata_ratio, 0.5);
//! assert!(tree.describe().contains("front_end.dynamic.judge.ata_ratio = 0.5  # --set"));
//! ```

use std::path::Path;

use serde::{Deserialize, Serialize};
use stillpoint_detect::DetectSettings;
use stillpoint_features::OrbParams;
use stillpoint_frontend::FrontEndSettings;
use stillpoint_pipeline::PipelineSettings;
use stillpoint_pipeline::settings::{self, SettingsError};
use stillpoint_slam::SlamSettings;
use stillpoint_slam::matching::stereo::StereoParams;

/// A settings tree and where each of its values came from.
pub type Layered = settings::Layered<SettingsTree>;

/// Every parameter of a run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SettingsTree {
    /// Tracking, local mapping and loop closing (`slam.loop_closing`); the camera comes from
    /// the dataset.
    pub slam: SlamSettings,
    /// ORB extraction.
    pub orb: OrbParams,
    /// Stereo matching along the rows (stereo pairs only).
    pub stereo: StereoParams,
    /// The dynamic front-end; the paper's rules and ours are under `front_end.dynamic`.
    pub front_end: FrontEndSettings,
    /// The YOLOX detector.
    pub detect: DetectSettings,
    /// The dense static cloud (`run --dense-cloud`).
    #[serde(default)]
    pub dense: stillpoint_pipeline::dense::DenseSettings,
    /// The MCAP recording (`run --record`).
    #[serde(default)]
    pub record: RecordSettings,
    /// The replay at camera rate (`run --realtime`).
    #[serde(default)]
    pub realtime: RealtimeSettings,
    /// How a recording's frames are read (`run` without `--realtime`).
    #[serde(default)]
    pub read: ReadSettings,
    /// The ROS 2 node (`stillpoint ros2`): topics, frames, quality of service.
    #[serde(default)]
    pub ros2: Ros2Settings,
}

/// What `stillpoint ros2` subscribes to and publishes (`[ros2]` in the settings tree). Topic
/// defaults are a RealSense driver's (`realsense2_camera`, depth aligned to colour).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Ros2Settings {
    /// `rgbd`, `stereo` or `mono`.
    pub sensor: String,
    /// The colour (or left, or only) image: `sensor_msgs/Image` or, with a `/compressed`
    /// suffix, `sensor_msgs/CompressedImage`.
    pub image_topic: String,
    /// The depth image registered to the colour one (`16UC1` millimetres or `32FC1` metres).
    pub depth_topic: String,
    /// The right image of a rectified pair.
    pub right_topic: String,
    /// The colour camera's `CameraInfo`; empty: `camera_info` beside `image_topic`.
    pub camera_info_topic: String,
    /// The right camera's `CameraInfo` (its projection gives the baseline); empty: beside
    /// `right_topic`.
    pub right_camera_info_topic: String,
    /// Images of one frame are paired when their stamps differ by at most this, seconds.
    pub pair_tolerance_s: f64,
    /// Subscribe reliably (the default is ROS's sensor-data profile: best effort, keep last).
    pub reliable: bool,
    /// Messages kept per subscription before the oldest is dropped.
    pub queue_depth: i32,
    /// The map's frame.
    pub map_frame: String,
    /// The robot's odometry frame (REP 105): when set, `map` -> `odom` is published, the
    /// robot's own `odom` -> ... -> camera transforms on `/tf` and `/tf_static` closing the
    /// chain; empty: `map` -> the camera's frame (a bare camera).
    pub odom_frame: String,
    /// The camera's frame; empty: the images' `header.frame_id`.
    pub camera_frame: String,
    /// Where the outputs go: `<prefix>/odom`, `/path`, `/map_cloud`, `/image_annotated`,
    /// `/state`.
    pub output_prefix: String,
    /// Seconds between map clouds (0: none).
    pub cloud_period_s: f64,
    /// Publish the annotated image (kept and culled keypoints, boxes) as JPEG.
    pub annotated_image: bool,
    /// JPEG quality of the annotated image.
    pub jpeg_quality: u8,
    /// A log line when no frame came for this many seconds.
    pub silence_warning_s: f64,
    /// The UDP receive buffer asked of the kernel, MiB: 4 holds two 640x480 colour and depth
    /// frames (Linux caps it at `net.core.rmem_max`; raise that for more).
    pub socket_buffer_mib: usize,
}

impl Default for Ros2Settings {
    fn default() -> Self {
        Self {
            sensor: "rgbd".into(),
            image_topic: "/camera/camera/color/image_raw".into(),
            depth_topic: "/camera/camera/aligned_depth_to_color/image_raw".into(),
            right_topic: String::new(),
            camera_info_topic: String::new(),
            right_camera_info_topic: String::new(),
            pair_tolerance_s: 0.02,
            reliable: false,
            queue_depth: 5,
            map_frame: "map".into(),
            odom_frame: String::new(),
            camera_frame: String::new(),
            output_prefix: "/stillpoint".into(),
            cloud_period_s: 1.0,
            annotated_image: true,
            jpeg_quality: 80,
            silence_warning_s: 5.0,
            socket_buffer_mib: 4,
        }
    }
}

/// How `run --realtime` replays a sequence (`[realtime]` in the settings tree).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RealtimeSettings {
    /// Decode the whole sequence before the clock starts when it fits in this many MiB (0:
    /// never). A camera hands over decoded frames; decoding a dataset's PNGs at 30 Hz took
    /// ~4 ms of the two cores' time a frame, which a robot's camera does not cost.
    pub preload_mib: usize,
    /// Deliver frame `i` at `i / rate_hz` seconds instead of at its timestamp (0: the
    /// timestamps), to replay a 30 Hz recording as a 60 Hz camera (`bench realtime --rate`).
    #[serde(default)]
    pub rate_hz: f64,
}

impl Default for RealtimeSettings {
    fn default() -> Self {
        Self {
            preload_mib: 2048,
            rate_hz: 0.0,
        }
    }
}

/// How a recording's frames are read in order (`[read]` in the settings tree).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReadSettings {
    /// Frames decoded ahead on a thread of their own while the pipeline works on the one
    /// before (0: each frame read on the pipeline's thread when its turn comes). Decoding a
    /// 640x480 RGB-D frame's two PNGs takes ~4 ms, which the pipeline's thread then waits for;
    /// the frames and so the trajectory are the same either way.
    pub ahead_frames: usize,
}

impl Default for ReadSettings {
    fn default() -> Self {
        Self { ahead_frames: 2 }
    }
}

/// What `run --record` puts in its MCAP file (`[record]` in the settings tree).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecordSettings {
    /// How each frame's colour image is stored: `jpeg` (small, fast), `png` (lossless, about
    /// ten times the bytes) or `none`.
    pub image: RecordImage,
    /// JPEG quality, 1..=100.
    pub jpeg_quality: u8,
    /// The map's points and keyframes are recorded after every this-many new keyframes (0:
    /// only at the end).
    pub map_every_keyframes: usize,
}

/// How `run --record` stores the frames' images.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RecordImage {
    /// foxglove.CompressedImage, JPEG.
    Jpeg,
    /// foxglove.CompressedImage, PNG.
    Png,
    /// No images (annotations, poses and points only).
    None,
}

impl Default for RecordSettings {
    fn default() -> Self {
        Self {
            image: RecordImage::Jpeg,
            jpeg_quality: 90,
            map_every_keyframes: 1,
        }
    }
}

impl SettingsTree {
    /// The defaults for a dataset: its camera, frame rate, depth and ORB settings, the crates'
    /// defaults for the rest.
    pub fn from_dataset(ds: &stillpoint_datasets::Settings) -> Self {
        let p = PipelineSettings::from_dataset(ds);
        let mut front_end = FrontEndSettings::default();
        if ds.sensor == stillpoint_datasets::Sensor::Stereo {
            // Where a stereo pair's dense depth is off (`stereo.dense_depth.enabled`), the
            // front-end judges it without depth; there the two-frame check's box-less outliers
            // are still worth heeding (stereo living_close s0, YOLOX: 4.7 cm with them, 16.4
            // without), where on a monocular camera they eat the static world.
            front_end.outlier_guard_without_depth = true;
            front_end.dynamic.cull.unknown_objects_without_depth = true;
        }
        Self {
            slam: p.slam,
            orb: p.orb,
            stereo: p.stereo,
            front_end,
            detect: DetectSettings::default(),
            dense: Default::default(),
            record: Default::default(),
            realtime: Default::default(),
            read: Default::default(),
            ros2: Default::default(),
        }
    }

    /// The settings the pipeline itself takes. The SLAM side's pyramid is the extractor's
    /// (`orb.scale_factor`, `orb.n_levels`), whatever layer set it.
    pub fn pipeline(&self) -> PipelineSettings {
        let mut slam = self.slam.clone();
        slam.scale_factor = f64::from(self.orb.scale_factor);
        slam.n_levels = self.orb.n_levels.max(1);
        PipelineSettings {
            slam,
            orb: self.orb.clone(),
            stereo: self.stereo.clone(),
        }
    }

    /// These settings with the tables of `files` (in order), then the `key=value` overrides,
    /// laid over them. Tables of a file that belong to the dataset's settings (`camera`,
    /// `camera.distortion`, top-level dataset keys) are not part of the tree and are skipped only
    /// when `dataset_file` is set for that file; any other unknown key is an error.
    pub fn layered(self, files: &[&Path], overrides: &[String]) -> Result<Layered, SettingsError> {
        self.layered_with(files.iter().map(|f| (*f, false)), overrides)
    }

    /// [`SettingsTree::layered`] where each file says whether it is also the dataset's settings
    /// file (a synthetic sequence's `settings.toml` with `[camera]`, `[orb]`, `[detect]`): then
    /// only its `detect` table is read into the tree (its `orb` and camera reached the tree
    /// through the dataset already).
    pub fn layered_with<'a>(
        self,
        files: impl IntoIterator<Item = (&'a Path, bool)>,
        overrides: &[String],
    ) -> Result<Layered, SettingsError> {
        let layered = settings::layered(
            &self,
            files,
            overrides,
            &["detect"],
            &["slam.camera.distortion."],
        )?;
        check_ranges(&layered)?;
        Ok(layered)
    }
}

/// The camera, frame rate and ORB values every dataset reader checks
/// ([`check_values`]), checked again once files and `--set` are laid over them: `--set
/// slam.fps=0` or `--set orb.scale_factor=0.5` ran before and made nonsense.
fn check_ranges(l: &Layered) -> Result<(), SettingsError> {
    use stillpoint_datasets::settings_file::{Field, check_values};
    let t = &l.tree;
    let mut s = stillpoint_datasets::Settings::with_camera(
        stillpoint_datasets::Sensor::Mono,
        t.slam.camera,
    );
    s.fps = t.slam.fps;
    s.th_depth = t.slam.th_depth;
    s.orb = t.orb.clone();
    let key = |field: Field| {
        let key = match field {
            Field::Fx => "slam.camera.fx",
            Field::Fy => "slam.camera.fy",
            Field::Cx => "slam.camera.cx",
            Field::Cy => "slam.camera.cy",
            Field::Fps => "slam.fps",
            Field::Bf => "slam.bf",
            Field::ThDepth => "slam.th_depth",
            Field::ScaleFactor => "orb.scale_factor",
            Field::NFeatures => "orb.n_features",
            Field::NLevels => "orb.n_levels",
            Field::NoiseThFactor => "orb.noise_th_factor",
            // the message gives both as WxH; named by the one set, if one was
            Field::Size if l.sources.contains_key("slam.camera.height") => "slam.camera.height",
            Field::Size => "slam.camera.width",
            // not part of the tree (a dataset's own setting, checked where it is read)
            Field::DepthFactor => "depth_factor",
        };
        // as the layering's own errors name them: the file and line, or the whole `--set`
        let origin = match l.sources.get(key) {
            None => "the dataset's settings".to_string(),
            Some(settings::Source::CommandLine) => {
                let value = l.entries().into_iter().find(|(k, ..)| k == key);
                format!(
                    "--set {key}={}",
                    value.map(|(_, v, _)| v).unwrap_or_default()
                )
            }
            Some(source) => source.to_string(),
        };
        format!("{origin}: `{key}`")
    };
    check_values(&s, key).map_err(SettingsError::OutOfRange)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tree() -> SettingsTree {
        let camera = stillpoint_geometry::PinholeCamera::new(535.4, 539.2, 320.1, 247.6, 640, 480);
        let ds =
            stillpoint_datasets::Settings::with_camera(stillpoint_datasets::Sensor::Rgbd, camera);
        SettingsTree::from_dataset(&ds)
    }

    #[test]
    fn a_file_then_overrides_set_values_and_remember_where() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("stillpoint.toml");
        std::fs::write(
            &path,
            "# mine\n[front_end.dynamic.world]\nenabled = false\n\n[detect]\nconf_threshold = 0.5\n",
        )
        .unwrap();
        let l = tree()
            .layered(
                &[&path],
                &[
                    "detect.conf_threshold=0.3".into(),
                    "orb.n_features=1500".into(),
                ],
            )
            .unwrap();
        assert!(!l.tree.front_end.dynamic.world.enabled);
        assert_eq!(l.tree.detect.conf_threshold, 0.3);
        assert_eq!(l.tree.orb.n_features, 1500);
        let d = l.describe();
        let world = format!(
            "front_end.dynamic.world.enabled = false  # {}:3",
            path.display()
        );
        assert!(d.contains(&world), "{d}");
        assert!(d.contains("detect.conf_threshold = 0.3  # --set"), "{d}");
        assert!(
            d.contains("front_end.dynamic.judge.ata_ratio = 0.4  # default"),
            "{d}"
        );
    }

    /// The pyramid has one home, `orb`: an override there reaches tracking and mapping (their
    /// octave scales and weights), and the SLAM side has no copy to set apart.
    #[test]
    fn the_orb_pyramid_reaches_the_slam_side() {
        let l = tree()
            .layered(
                &[],
                &["orb.scale_factor=1.3".into(), "orb.n_levels=6".into()],
            )
            .unwrap();
        let p = l.tree.pipeline();
        assert_eq!(p.slam.scale_factor, f64::from(1.3f32));
        assert_eq!(p.slam.n_levels, 6);
        let e = tree()
            .layered(&[], &["slam.scale_factor=1.3".into()])
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "--set slam.scale_factor=1.3: `slam.scale_factor` is no longer a setting of its own: set `orb.scale_factor`"
        );
        assert!(!l.describe().contains("slam.scale_factor"));
    }

    #[test]
    fn an_unknown_key_names_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.toml");
        std::fs::write(
            &path,
            "[front_end]\nmovable_hygiene = true\nmovable_hygeine = false\n",
        )
        .unwrap();
        let e = tree().layered(&[&path], &[]).unwrap_err().to_string();
        assert_eq!(
            e,
            format!(
                "{}:3: unknown key `front_end.movable_hygeine`",
                path.display()
            )
        );
        let e = tree()
            .layered(&[], &["slam.no_such=1".into()])
            .unwrap_err()
            .to_string();
        assert_eq!(e, "--set slam.no_such=1: unknown key `slam.no_such`");
        // A removed setting is named with what does its work now.
        let e = tree()
            .layered(&[], &["slam.kf_count_blocked_close=true".into()])
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("--set slam.kf_count_blocked_close=true: `slam.kf_count_blocked_close` was removed: "),
            "{e}"
        );
        // The detector's table denies unknown fields itself: the same error.
        std::fs::write(&path, "[detect]\nthreads = 2\nconf_treshold = 0.2\n").unwrap();
        let e = tree().layered(&[&path], &[]).unwrap_err().to_string();
        assert_eq!(
            e,
            format!("{}:3: unknown key `detect.conf_treshold`", path.display())
        );
    }

    #[test]
    fn a_value_of_the_wrong_kind_is_an_error_naming_the_key() {
        let e = tree()
            .layered(&[], &["orb.n_features=many".into()])
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("--set orb.n_features=many: `orb.n_features`"),
            "{e}"
        );
        assert!(matches!(
            tree().layered(&[], &["orb.n_features".into()]),
            Err(SettingsError::BadOverride { .. })
        ));
    }

    #[test]
    fn a_number_no_setting_takes_is_an_error_naming_the_key() {
        let err = |set: &str| {
            tree()
                .layered(&[], &[set.to_string()])
                .unwrap_err()
                .to_string()
        };
        assert_eq!(
            err("slam.fps=0"),
            "--set slam.fps=0.0: `slam.fps` = 0: frames per second must be positive"
        );
        assert_eq!(
            err("slam.fps=nan"),
            "--set slam.fps=nan: `slam.fps`: not a number"
        );
        assert_eq!(
            err("slam.mono_init.window_px=-10"),
            "--set slam.mono_init.window_px=-10: `slam.mono_init.window_px`: -10 is negative; \
             this setting is 0 or more"
        );
        assert_eq!(
            err("detect.conf_threshold=2"),
            "--set detect.conf_threshold=2: `detect.conf_threshold`: 2 is over 1; this setting \
             is 0 to 1"
        );
        assert!(err("orb.n_levels=0").starts_with("--set orb.n_levels=0: `orb.n_levels` = 0: "));
        // from a file: its line
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.toml");
        std::fs::write(&path, "[orb]\nn_features = 1000\nscale_factor = 0.5\n").unwrap();
        let e = tree().layered(&[&path], &[]).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("{}:3: `orb.scale_factor` = 0.5: ", path.display())),
            "{e}"
        );
        // what may be negative or unbounded stays allowed
        let ok = [
            "slam.camera.distortion.k1=-0.2",
            "front_end.dynamic.keypoint_motion.cull_above_px=inf",
            "front_end.background_detect_nice=-2",
        ];
        let l = tree().layered(&[], &ok.map(String::from)).unwrap();
        assert_eq!(l.tree.slam.camera.distortion.k1, -0.2);
    }

    #[test]
    fn every_default_set_again_is_taken() {
        for ds in [
            stillpoint_datasets::Sensor::Rgbd,
            stillpoint_datasets::Sensor::Mono,
            stillpoint_datasets::Sensor::Stereo,
        ] {
            let camera =
                stillpoint_geometry::PinholeCamera::new(535.4, 539.2, 320.1, 247.6, 640, 480);
            let base =
                SettingsTree::from_dataset(&stillpoint_datasets::Settings::with_camera(ds, camera));
            let sets: Vec<String> = base
                .clone()
                .layered(&[], &[])
                .unwrap()
                .entries()
                .into_iter()
                .map(|(key, value, _)| format!("{key}={value}"))
                .collect();
            if let Err(e) = base.layered(&[], &sets) {
                panic!("{ds:?}: {e}");
            }
        }
    }

    #[test]
    fn the_defaults_round_trip() {
        let l = tree().layered(&[], &[]).unwrap();
        assert_eq!(
            format!("{:?}", l.tree.front_end),
            format!("{:?}", FrontEndSettings::default())
        );
        assert!(l.sources.is_empty());
    }
}
