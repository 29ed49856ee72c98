//! The ORB extractor's settings, which a sequence's settings carry (`ORBextractor.*`) and the
//! extractor and the SLAM side's pyramid take.

/// ORB extractor settings. `Default` = ORB-SLAM3's TUM settings (`ORBextractor.*` in
/// `TUM1.yaml`, the values the paper used); KITTI stereo uses `n_features: 2000`.
/// Datasets carry it in their settings (`datasets::Settings::orb`, `[orb]` in a settings file);
/// a key it does not have is an error there, not a silent default.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OrbParams {
    /// Target number of features per image (`ORBextractor.nFeatures`: 1000 TUM, 2000 KITTI).
    pub n_features: usize,
    /// Scale between pyramid levels (`ORBextractor.scaleFactor`: 1.2).
    pub scale_factor: f32,
    /// Number of pyramid levels (`ORBextractor.nLevels`: 8).
    pub n_levels: usize,
    /// FAST threshold tried first in each cell (`ORBextractor.iniThFAST`: 20).
    pub ini_th_fast: u8,
    /// FAST threshold used in cells where the first found nothing (`ORBextractor.minThFAST`: 7).
    pub min_th_fast: u8,
    /// A third, lower FAST threshold for cells where `min_th_fast` found nothing too: plain walls
    /// and floors (ORB-SLAM's 7 leaves them empty and the map thins out on a turn). 0 = off.
    #[serde(default = "default_low_texture_th_fast")]
    pub low_texture_th_fast: u8,
    /// The third threshold is raised to this many times the image's noise (sigma estimated on
    /// each frame, Immerkaer 1996), so a noisy sensor does not fill plain cells with noise.
    #[serde(default = "default_noise_th_factor")]
    pub noise_th_factor: f32,
    /// Each keypoint's position refined below the pixel, where the image gradients of the 7x7
    /// window round it meet (Förstner's corner point, as OpenCV's `cornerSubPix`); orientation
    /// and descriptor stay those of the pixel. FAST finds corners on whole pixels of their
    /// level, so without it a keypoint on level 3 sits up to 0.9 px from its corner.
    #[serde(default)]
    pub subpixel: bool,
}

fn default_low_texture_th_fast() -> u8 {
    3
}

fn default_noise_th_factor() -> f32 {
    2.0
}

impl Default for OrbParams {
    fn default() -> Self {
        Self {
            n_features: 1000,
            scale_factor: 1.2,
            n_levels: 8,
            ini_th_fast: 20,
            min_th_fast: 7,
            low_texture_th_fast: default_low_texture_th_fast(),
            noise_th_factor: default_noise_th_factor(),
            subpixel: false,
        }
    }
}
