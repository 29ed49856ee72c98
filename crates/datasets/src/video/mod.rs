//! Video files as a monocular [`Sequence`]: H.264 in MP4 (`.mp4`, `.mov`, `.m4v`), what phones,
//! action cameras and `ffmpeg -c:v libx264` write. Feature `video` (on by default): the
//! demuxer is the `mp4` crate, the decoder Cisco's openh264 compiled from its bundled source, so
//! no system library is needed.
//!
//! Opening reads the top-level boxes and the `moov` box (the sample table) and decodes the first
//! frame (its size is the camera's); [`Sequence::frame`] then decodes forward, keeping the
//! decoder between frames. Frame `i` is the `i`-th picture in presentation order, stamped with
//! its sample's composition time (seconds from the start of the track).
//!
//! The camera is the settings file's; without one it is a pinhole guessed from the image size
//! with a 60° horizontal field of view (logged as a warning: give `--settings` for real use).
//!
//! A file cut short (a recording that was stopped by pulling the power, a partial copy) keeps
//! the frames before the cut: the first sample past the end of the file, or one the decoder
//! rejects, is a [`DatasetError::Ended`] naming the file, the sample and its byte. A file cut
//! before its `moov` box (recorders write it last) cannot be decoded at all: that is an error
//! when opening, naming the byte where the file ends.

#[cfg(feature = "video")]
mod mp4file;
#[cfg(feature = "video")]
mod sequence;
#[cfg(feature = "video")]
pub mod write;

#[cfg(feature = "video")]
pub use sequence::VideoSequence;

use crate::error::DatasetError;
use crate::sequence::Sequence;
use std::path::Path;

/// Horizontal field of view of the camera guessed when no settings are given, degrees.
pub const GUESSED_HFOV_DEG: f64 = 60.0;

/// Open a video file as a monocular sequence; `settings` (ORB-SLAM YAML or our TOML) gives
/// the camera, else it is guessed ([`GUESSED_HFOV_DEG`]). Like [`crate::open`], frames of
/// another size than the camera are an error now rather than a skipped frame each.
pub fn open(path: &Path, settings: Option<&Path>) -> Result<Box<dyn Sequence>, DatasetError> {
    #[cfg(feature = "video")]
    {
        let seq = VideoSequence::open(path, settings)?;
        if let Err(e @ DatasetError::SizeMismatch { .. }) = seq.frame(0) {
            return Err(e);
        }
        Ok(Box::new(seq))
    }
    #[cfg(not(feature = "video"))]
    {
        let _ = settings;
        Err(crate::error::layout_err(
            path,
            "this stillpoint was built without video support (cargo feature `video`, on by default)",
        ))
    }
}

/// A pinhole camera for a `width` x `height` image with a [`GUESSED_HFOV_DEG`] horizontal
/// field of view, principal point at the centre.
pub fn guessed_camera(width: u32, height: u32) -> stillpoint_geometry::PinholeCamera {
    let (w, h) = (f64::from(width), f64::from(height));
    let f = (w / 2.0) / (GUESSED_HFOV_DEG.to_radians() / 2.0).tan();
    stillpoint_geometry::PinholeCamera::new(f, f, w / 2.0, h / 2.0, width, height)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_guessed_camera_sees_60_degrees_across() {
        let c = guessed_camera(640, 480);
        let hfov = 2.0 * (320.0 / c.fx).atan();
        assert!((hfov.to_degrees() - 60.0).abs() < 1e-9);
        assert_eq!((c.cx, c.cy, c.fx), (320.0, 240.0, c.fy));
    }
}
