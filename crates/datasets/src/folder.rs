//! A plain folder of images (monocular), sorted by file name, at the settings' frame rate.

use crate::error::{DatasetError, io_err, layout_err};
use crate::sequence::{
    Sequence, check_header, check_index, check_size, dir_name, header_size, is_image,
};
use crate::settings_file::{Field, check_values};
use crate::{Frame, Sensor, Settings};
use std::path::{Path, PathBuf};
use stillpoint_geometry::PinholeCamera;
use stillpoint_image::{read_rgb, rgb_to_gray};

/// Images of a folder; frame i is at i / fps seconds.
pub struct FolderSequence {
    dir: PathBuf,
    settings: Settings,
    images: Vec<PathBuf>,
}

impl FolderSequence {
    /// Open `dir`. Without settings (given, or `settings.toml` in `dir`) the camera is a guess
    /// from the first image: fx = fy = width (about 53° horizontal field of view), principal
    /// point at the centre, 30 fps; logged as a warning.
    pub fn open(dir: &Path, settings: Option<Settings>) -> Result<Self, DatasetError> {
        let mut images: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io_err(dir))?
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| is_image(p))
            .collect();
        images.sort();
        if images.is_empty() {
            return Err(layout_err(dir, "no .png/.jpg images"));
        }
        let mut settings = match settings {
            Some(s) => s,
            None if dir.join("settings.toml").is_file() => {
                crate::read_settings_toml(&dir.join("settings.toml"))?
            }
            None => {
                let (width, height) = match header_size(&images[0]) {
                    Some(size) => size,
                    None => {
                        let img = read_rgb(&images[0])?;
                        (img.width, img.height)
                    }
                };
                let (w, h) = (width as f64, height as f64);
                tracing::warn!(
                    "{}: no settings; guessing fx = fy = {w}, centred principal point",
                    dir.display()
                );
                let s = Settings::with_camera(
                    Sensor::Mono,
                    PinholeCamera::new(w, w, w / 2.0, h / 2.0, width as u32, height as u32),
                );
                let key = |field: Field| match field {
                    Field::Size => format!("{}: image size", images[0].display()),
                    other => format!("{other:?} (guessed from the image size)"),
                };
                check_values(&s, key).map_err(|m| layout_err(dir, m))?;
                s
            }
        };
        settings.sensor = Sensor::Mono;
        if !(settings.fps > 0.0 && settings.fps.is_finite()) {
            return Err(layout_err(
                dir,
                format!("frame rate must be positive, got {}", settings.fps),
            ));
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            settings,
            images,
        })
    }
}

impl Sequence for FolderSequence {
    fn settings(&self) -> &Settings {
        &self.settings
    }
    fn len(&self) -> usize {
        self.images.len()
    }
    fn frame(&self, i: usize) -> Result<Frame, DatasetError> {
        check_index(i, self.images.len())?;
        check_header(&self.images[i], &self.settings)?;
        let rgb = read_rgb(&self.images[i])?;
        check_size(&self.images[i], rgb.width, rgb.height, &self.settings)?;
        Ok(Frame {
            index: i,
            timestamp: i as f64 / self.settings.fps,
            gray: rgb_to_gray(&rgb),
            rgb: Some(rgb),
            depth: None,
            right: None,
        })
    }
    fn ground_truth(&self) -> Option<PathBuf> {
        None
    }
    fn boxes(&self) -> Option<PathBuf> {
        Some(self.dir.join("boxes.jsonl")).filter(|p| p.is_file())
    }
    fn name(&self) -> String {
        dir_name(&self.dir)
    }
    fn timestamp(&self, i: usize) -> Option<f64> {
        (i < self.images.len()).then(|| i as f64 / self.settings.fps)
    }
}
