//! What a sequence's images are: the sensor, the camera and the ORB extractor's sizes, as
//! ORB-SLAM's settings files carry them.

use serde::{Deserialize, Serialize};
use stillpoint_geometry::{PinholeCamera, StereoRectification};

use crate::OrbParams;

/// What the sequence provides.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Sensor {
    /// Colour (or gray) and registered depth.
    Rgbd,
    /// A rectified stereo pair.
    Stereo,
    /// One camera.
    Mono,
}

/// Everything needed to interpret a sequence's images. A misspelt key is an error, not a
/// silent default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    /// What the sequence provides.
    pub sensor: Sensor,
    /// Left / only camera (distortion included).
    pub camera: PinholeCamera,
    /// Frames per second (`Camera.fps`; ORB-SLAM's default 30).
    #[serde(default = "default_fps")]
    pub fps: f64,
    /// Raw depth units per metre (`DepthMapFactor`; TUM 5000). Depth images are divided by it.
    #[serde(default = "default_depth_factor")]
    pub depth_factor: f64,
    /// Stereo baseline times fx, in pixel-metres (`Camera.bf`); RGB-D uses it for the virtual
    /// right coordinate and the close/far split.
    #[serde(default)]
    pub bf: Option<f64>,
    /// Close/far threshold in baselines (`ThDepth`): close when depth < th_depth * bf / fx.
    /// ORB-SLAM's TUM files use 40, its KITTI/EuRoC files 35.
    #[serde(default = "default_th_depth")]
    pub th_depth: f64,
    /// True when the images are RGB (`Camera.RGB: 1`), false for BGR.
    #[serde(default = "default_rgb")]
    pub rgb: bool,
    /// The ORB extractor's settings (`ORBextractor.*`; the extractor's own type, so the values
    /// reach it as read).
    #[serde(default)]
    pub orb: OrbParams,
    /// For a stereo camera whose images are not rectified (EuRoC): the raw cameras and the
    /// rectifying rotations and projections (ORB-SLAM's `LEFT.K/D/R/P`, `RIGHT.*`). The EuRoC
    /// reader then rectifies both images, and `camera` / `bf` describe the rectified pair.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rectification: Option<StereoRectification>,
}

fn default_fps() -> f64 {
    30.0
}
fn default_depth_factor() -> f64 {
    5000.0
}
fn default_th_depth() -> f64 {
    40.0
}
fn default_rgb() -> bool {
    true
}

impl Settings {
    /// Settings for `camera` with ORB-SLAM's TUM defaults for everything else (30 fps, depth
    /// factor 5000, `bf` 40, `ThDepth` 40, RGB order, 1000 ORB features).
    pub fn with_camera(sensor: Sensor, camera: PinholeCamera) -> Self {
        Self {
            sensor,
            camera,
            fps: default_fps(),
            depth_factor: default_depth_factor(),
            bf: Some(40.0),
            th_depth: default_th_depth(),
            rgb: true,
            orb: OrbParams::default(),
            rectification: None,
        }
    }

    /// Baseline in metres, when `bf` is known.
    pub fn baseline(&self) -> Option<f64> {
        self.bf.map(|bf| bf / self.camera.fx)
    }

    /// Depth below which a point is "close" (ORB-SLAM: ThDepth baselines).
    pub fn close_depth(&self) -> Option<f64> {
        self.baseline().map(|b| b * self.th_depth)
    }
}
