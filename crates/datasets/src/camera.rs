//! A live V4L2 camera (`run --camera /dev/video0`) as a [`crate::live::LiveSequence`]: MJPEG or
//! YUYV frames (what webcams offer), monocular, the newest frame handed to tracking and older
//! ones dropped, stamped with the wall clock when they are dequeued.
//!
//! Feature `camera` (the `v4l` crate). It is off by default: the crate's bindings are generated
//! by bindgen at build time, which needs libclang (`apt-get install libclang-dev`), and the
//! default build needs no system library. Without it [`open`] says how to get it.
//!
//! The camera is the settings file's; without one a pinhole with a 60° horizontal field of
//! view is guessed from the frame size (as for video files, logged as a warning). A missing or
//! busy device is one error naming it.

use crate::error::DatasetError;
use crate::sequence::Sequence;
use std::path::Path;

/// The error for a device that cannot be used, naming it.
pub fn device_err(path: &Path, msg: impl Into<String>) -> DatasetError {
    DatasetError::Ended {
        path: path.display().to_string(),
        at: "opening".into(),
        msg: msg.into(),
    }
}

/// What an `open(2)` / ioctl error on a camera means to its user.
pub fn explain(e: &std::io::Error) -> String {
    match e.raw_os_error() {
        Some(2) | Some(6) | Some(19) => format!(
            "no such camera ({e}): is it plugged in? `v4l2-ctl --list-devices` or `ls /dev/video*` lists them"
        ),
        Some(16) => format!(
            "the camera is busy ({e}): another program is capturing from it; close it and try again"
        ),
        Some(13) | Some(1) => {
            format!("no permission to open it ({e}): add yourself to the `video` group")
        }
        Some(25) => format!(
            "not a V4L2 camera ({e}): give a camera's device, e.g. /dev/video0 (`ls /dev/video*`)"
        ),
        _ => e.to_string(),
    }
}

/// Open the camera at `path` (`/dev/video0`); `settings` (ORB-SLAM YAML or our TOML) gives its
/// calibration.
pub fn open(path: &Path, settings: Option<&Path>) -> Result<Box<dyn Sequence>, DatasetError> {
    // Missing is said the same with or without the feature.
    if let Err(e) = std::fs::metadata(path) {
        return Err(device_err(path, explain(&e)));
    }
    #[cfg(feature = "camera")]
    {
        v4l2::open(path, settings)
    }
    #[cfg(not(feature = "camera"))]
    {
        let _ = settings;
        Err(device_err(
            path,
            "this stillpoint was built without camera support: build it with `--features camera` \
             (the v4l crate; its bindings need libclang at build time: apt-get install libclang-dev)",
        ))
    }
}

#[cfg(feature = "camera")]
mod v4l2 {
    use super::{device_err, explain};
    use crate::error::DatasetError;
    use crate::live::{Buffering, FrameSource, LiveSequence};
    use crate::sequence::Sequence;
    use crate::{Sensor, Settings};
    use std::path::{Path, PathBuf};
    use stillpoint_image::Rgb8;
    use v4l::buffer::Type;
    use v4l::io::mmap::Stream;
    use v4l::io::traits::CaptureStream;
    use v4l::video::Capture;
    use v4l::{Device, FourCC};

    /// Pixel formats we decode, in order of preference.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    enum Pixels {
        Mjpeg,
        Yuyv,
    }

    struct V4lSource {
        path: PathBuf,
        stream: Stream<'static>,
        /// Kept open for the stream's life.
        _device: Device,
        pixels: Pixels,
        size: (usize, usize),
        /// The first frame, read when opening.
        first: Option<(Rgb8, f64)>,
    }

    pub(super) fn open(
        path: &Path,
        settings: Option<&Path>,
    ) -> Result<Box<dyn Sequence>, DatasetError> {
        let settings = settings.map(crate::read_settings).transpose()?;
        let err = |e: std::io::Error| device_err(path, explain(&e));
        let device = Device::with_path(path).map_err(err)?;
        let caps = device.query_caps().map_err(err)?;
        if !caps
            .capabilities
            .contains(v4l::capability::Flags::VIDEO_CAPTURE)
        {
            return Err(device_err(
                path,
                format!(
                    "{} ({}) is not a video capture device: give a camera's device (`v4l2-ctl --list-devices`)",
                    caps.card, caps.driver
                ),
            ));
        }
        let formats = device.enum_formats().map_err(err)?;
        let offered: Vec<String> = formats.iter().map(|f| f.fourcc.to_string()).collect();
        let pixels = if formats.iter().any(|f| f.fourcc == FourCC::new(b"MJPG")) {
            Pixels::Mjpeg
        } else if formats.iter().any(|f| f.fourcc == FourCC::new(b"YUYV")) {
            Pixels::Yuyv
        } else {
            return Err(device_err(
                path,
                format!(
                    "offers none of MJPG, YUYV (it offers: {})",
                    offered.join(", ")
                ),
            ));
        };
        let mut fmt = device.format().map_err(err)?;
        fmt.fourcc = FourCC::new(match pixels {
            Pixels::Mjpeg => b"MJPG",
            Pixels::Yuyv => b"YUYV",
        });
        if let Some(s) = &settings {
            (fmt.width, fmt.height) = (s.camera.width, s.camera.height);
        }
        let fmt = device.set_format(&fmt).map_err(err)?;
        let stream = Stream::with_buffers(&device, Type::VideoCapture, 4).map_err(err)?;
        let mut source = V4lSource {
            path: path.to_path_buf(),
            stream,
            _device: device,
            pixels,
            size: (fmt.width as usize, fmt.height as usize),
            first: None,
        };
        let first = source
            .grab()?
            .ok_or_else(|| device_err(path, "gave no frame"))?;
        let (w, h) = (first.0.width as u32, first.0.height as u32);
        let mut settings = match settings {
            Some(s) => s,
            None => {
                let camera = crate::video::guessed_camera(w, h);
                tracing::warn!(
                    "{}: no settings; guessing a pinhole camera with a {}° horizontal field of \
                     view (fx = fy = {:.1}): give --settings with this camera's calibration",
                    path.display(),
                    crate::video::GUESSED_HFOV_DEG,
                    camera.fx
                );
                Settings::with_camera(Sensor::Mono, camera)
            }
        };
        settings.sensor = Sensor::Mono;
        if (w, h) != (settings.camera.width, settings.camera.height) {
            return Err(DatasetError::SizeMismatch {
                path: path.display().to_string(),
                width: w as usize,
                height: h as usize,
                expected_width: settings.camera.width,
                expected_height: settings.camera.height,
            });
        }
        tracing::info!(
            "{}: {w}x{h} {:?} (offers {})",
            path.display(),
            pixels,
            offered.join(", ")
        );
        source.first = Some(first);
        Ok(Box::new(LiveSequence::start(
            Box::new(source),
            settings,
            Buffering::Newest,
        )?))
    }

    impl V4lSource {
        /// Dequeue and decode one frame.
        fn grab(&mut self) -> Result<Option<(Rgb8, f64)>, DatasetError> {
            let (buf, meta) = self
                .stream
                .next()
                .map_err(|e| device_err(&self.path, explain(&e)))?;
            let stamp = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64());
            let bytes = &buf[..(meta.bytesused as usize).min(buf.len())];
            let rgb = match self.pixels {
                Pixels::Mjpeg => stillpoint_image::codec::decode(bytes)
                    .map_err(|e| {
                        device_err(&self.path, format!("frame {}: MJPEG: {e}", meta.sequence))
                    })?
                    .to_rgb8(),
                Pixels::Yuyv => {
                    super::yuyv_to_rgb(bytes, self.size.0, self.size.1).ok_or_else(|| {
                        device_err(
                            &self.path,
                            format!("frame {}: a short YUYV frame", meta.sequence),
                        )
                    })?
                }
            };
            Ok(Some((rgb, stamp)))
        }
    }

    impl FrameSource for V4lSource {
        fn next_frame(&mut self) -> Result<Option<(Rgb8, f64)>, DatasetError> {
            match self.first.take() {
                Some(f) => Ok(Some(f)),
                None => self.grab(),
            }
        }
        fn name(&self) -> String {
            self.path.display().to_string()
        }
    }
}

/// YUYV 4:2:2 (Y0 U Y1 V per two pixels) to RGB, BT.601 limited range (what webcams send).
/// `None` when `b` is shorter than a `w` x `h` frame.
pub fn yuyv_to_rgb(b: &[u8], w: usize, h: usize) -> Option<stillpoint_image::Rgb8> {
    if b.len() < w * h * 2 || !w.is_multiple_of(2) {
        return None;
    }
    let px = |y: u8, u: u8, v: u8| {
        let (c, d, e) = (
            f32::from(y) - 16.0,
            f32::from(u) - 128.0,
            f32::from(v) - 128.0,
        );
        let k = |x: f32| x.round().clamp(0.0, 255.0) as u8;
        [
            k(1.164 * c + 1.596 * e),
            k(1.164 * c - 0.392 * d - 0.813 * e),
            k(1.164 * c + 2.017 * d),
        ]
    };
    let data = b[..w * h * 2]
        .chunks_exact(4)
        .flat_map(|q| [px(q[0], q[1], q[3]), px(q[2], q[1], q[3])])
        .collect();
    Some(stillpoint_image::Rgb8 {
        width: w,
        height: h,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_device_is_one_error_naming_it() {
        let e = open(Path::new("/dev/video-stillpoint-none"), None)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.starts_with("/dev/video-stillpoint-none: opening: no such camera"),
            "{e}"
        );
        assert!(e.contains("v4l2-ctl --list-devices"), "{e}");
    }

    #[test]
    fn busy_and_forbidden_devices_are_explained() {
        let busy = explain(&std::io::Error::from_raw_os_error(16));
        assert!(busy.starts_with("the camera is busy"), "{busy}");
        let denied = explain(&std::io::Error::from_raw_os_error(13));
        assert!(denied.contains("`video` group"), "{denied}");
    }

    #[test]
    fn yuyv_grey_and_white_decode() {
        // Two pixels of mid grey (Y 126, no colour), two of white (Y 235).
        let rgb = yuyv_to_rgb(&[126, 128, 126, 128, 235, 128, 235, 128], 4, 1).unwrap();
        assert_eq!(rgb.data, vec![[128; 3], [128; 3], [255; 3], [255; 3]]);
        assert!(yuyv_to_rgb(&[0; 6], 4, 1).is_none());
    }
}
