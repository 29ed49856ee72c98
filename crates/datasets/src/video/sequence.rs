//! [`VideoSequence`]: the decoder kept between frames, decoding forward.

use super::mp4file::{Track, read_track, to_annex_b};
use crate::error::{DatasetError, io_err, layout_err};
use crate::sequence::{Sequence, check_index};
use crate::{Frame, Sensor, Settings};
use openh264::decoder::{DecodedYUV, Decoder, DecoderConfig, Flush};
use openh264::formats::YUVSource;
use std::collections::VecDeque;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use stillpoint_image::{Rgb8, rgb_to_gray};

/// An H.264 video as a monocular sequence.
pub struct VideoSequence {
    path: PathBuf,
    settings: Settings,
    track: Track,
    /// Presentation stamps, seconds, sorted: frame `i` is shown at `stamps[i]`.
    stamps: Vec<f64>,
    state: Mutex<Decoding>,
}

/// Where decoding stands.
struct Decoding {
    file: File,
    decoder: Decoder,
    /// Next sample to feed.
    next_sample: usize,
    /// Pictures decoded and not yet taken, with their frame index.
    pictures: VecDeque<(usize, Rgb8)>,
    /// Index the next decoded picture gets.
    next_picture: usize,
    /// The stream can give no more: why (None at its normal end, after the decoder is flushed).
    ended: Option<Option<DatasetError>>,
}

impl VideoSequence {
    /// Open `path`; the settings file `settings` gives the camera (its image size may be left
    /// out: the stream gives it), else [`super::guessed_camera`] of the first frame's size. The
    /// frame rate is the samples' median rate.
    pub fn open(path: &Path, settings: Option<&Path>) -> Result<Self, DatasetError> {
        let track = read_track(path)?;
        let mut stamps: Vec<f64> = track
            .samples
            .iter()
            .map(|s| s.composition as f64 / f64::from(track.timescale))
            .collect();
        stamps.sort_by(f64::total_cmp);
        let state = Mutex::new(Decoding::start(path)?);
        let mut seq = Self {
            path: path.to_path_buf(),
            // Replaced below, once the first picture's size is known.
            settings: Settings::with_camera(Sensor::Mono, super::guessed_camera(2, 2)),
            track,
            stamps,
            state,
        };
        let first = seq.picture(0)?;
        let mut settings = match settings {
            Some(file) => {
                crate::read_settings_for_images(file, (first.width as u32, first.height as u32))?
            }
            None => {
                let camera = super::guessed_camera(first.width as u32, first.height as u32);
                tracing::warn!(
                    "{}: no settings; guessing a pinhole camera with a {}° horizontal field of view \
                     (fx = fy = {:.1}, centred principal point): give --settings with this camera's \
                     calibration for metric accuracy",
                    path.display(),
                    super::GUESSED_HFOV_DEG,
                    camera.fx
                );
                Settings::with_camera(Sensor::Mono, camera)
            }
        };
        settings.sensor = Sensor::Mono;
        if let Some(fps) = frame_rate(&seq.stamps) {
            settings.fps = fps;
        }
        if !(settings.fps > 0.0 && settings.fps.is_finite()) {
            return Err(layout_err(
                path,
                format!("frame rate must be positive, got {}", settings.fps),
            ));
        }
        seq.settings = settings;
        tracing::info!(
            "{}: {} frames of {}x{} H.264, {:.1} s at {} fps",
            path.display(),
            seq.track.samples.len(),
            first.width,
            first.height,
            seq.stamps.last().copied().unwrap_or(0.0) - seq.stamps[0],
            seq.settings.fps
        );
        Ok(seq)
    }

    /// The `i`-th picture in presentation order, decoding forward to it (from the start again
    /// when it was passed).
    fn picture(&self, i: usize) -> Result<Rgb8, DatasetError> {
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        if st.pictures.front().is_none_or(|(k, _)| *k > i) && st.next_picture > i {
            *st = Decoding::start(&self.path)?;
        }
        loop {
            while st.pictures.front().is_some_and(|(k, _)| *k < i) {
                st.pictures.pop_front();
            }
            if let Some((_, p)) = st.pictures.front().filter(|(k, _)| *k == i) {
                return Ok(p.clone());
            }
            if let Some(ended) = &st.ended {
                return Err(match ended {
                    Some(e) => clone_error(e),
                    None => DatasetError::Ended {
                        path: self.path.display().to_string(),
                        at: format!("frame {i}"),
                        msg: format!(
                            "the decoder gave {} pictures for {} samples",
                            st.next_picture,
                            self.track.samples.len()
                        ),
                    },
                });
            }
            self.decode_next(&mut st);
        }
    }

    /// Feed the next sample (or flush the decoder after the last), keeping its pictures; a
    /// sample that cannot be read or decoded ends the stream.
    fn decode_next(&self, st: &mut Decoding) {
        let k = st.next_sample;
        let Some(sample) = self.track.samples.get(k) else {
            let flushed = st
                .decoder
                .flush_remaining()
                .map(|pics| pics.iter().map(to_rgb).collect::<Vec<_>>());
            match flushed {
                Ok(pics) => {
                    for p in pics {
                        let n = st.next_picture;
                        st.pictures.push_back((n, p));
                        st.next_picture += 1;
                    }
                    st.ended = Some(None);
                }
                Err(e) => {
                    st.ended = Some(Some(self.sample_err(k.saturating_sub(1), e.to_string())))
                }
            }
            return;
        };
        st.next_sample += 1;
        let end = sample.offset + u64::from(sample.size);
        if end > self.track.file_len {
            st.ended = Some(Some(self.sample_err(
                k,
                format!(
                    "the file ends at byte {} before this sample's {} bytes: it was cut short \
                     ({k} of {} samples are whole)",
                    self.track.file_len,
                    sample.size,
                    self.track.samples.len()
                ),
            )));
            return;
        }
        let mut bytes = vec![0u8; sample.size as usize];
        if let Err(e) = st
            .file
            .seek(SeekFrom::Start(sample.offset))
            .and_then(|_| st.file.read_exact(&mut bytes))
        {
            st.ended = Some(Some(self.sample_err(k, e.to_string())));
            return;
        }
        let mut annex_b = Vec::with_capacity(bytes.len() + 64);
        if k == 0 || sample.sync {
            for ps in &self.track.parameter_sets {
                annex_b.extend_from_slice(&[0, 0, 0, 1]);
                annex_b.extend_from_slice(ps);
            }
        }
        if let Err(e) = to_annex_b(&bytes, self.track.length_size, &mut annex_b) {
            st.ended = Some(Some(self.sample_err(k, e)));
            return;
        }
        match st.decoder.decode(&annex_b) {
            Ok(Some(pic)) => {
                let p = to_rgb(&pic);
                let n = st.next_picture;
                st.pictures.push_back((n, p));
                st.next_picture += 1;
            }
            Ok(None) => {}
            Err(e) => {
                st.ended = Some(Some(
                    self.sample_err(k, format!("the H.264 decoder rejects it: {e}")),
                ));
            }
        }
    }

    /// The error that ends the stream at sample `k`: the file, the sample and its byte.
    fn sample_err(&self, k: usize, msg: String) -> DatasetError {
        let byte = self.track.samples.get(k).map_or(0, |s| s.offset);
        DatasetError::Ended {
            path: self.path.display().to_string(),
            at: format!("sample {k} (byte {byte})"),
            msg,
        }
    }
}

/// [`DatasetError`] holds an `io::Error`, which is not `Clone`: the stored end is given again
/// as a copy of its text where it is not one of ours.
fn clone_error(e: &DatasetError) -> DatasetError {
    match e {
        DatasetError::Ended { path, at, msg } => DatasetError::Ended {
            path: path.clone(),
            at: at.clone(),
            msg: msg.clone(),
        },
        other => DatasetError::Ended {
            path: String::new(),
            at: String::new(),
            msg: other.to_string(),
        },
    }
}

impl Decoding {
    fn start(path: &Path) -> Result<Self, DatasetError> {
        let file = File::open(path).map_err(io_err(path))?;
        // No flush after each sample: with B-frames a picture comes out once the ones shown
        // before it are decoded, so pictures arrive in presentation order.
        let config = DecoderConfig::new().flush_after_decode(Flush::NoFlush);
        let decoder = Decoder::with_api_config(openh264::OpenH264API::from_source(), config)
            .map_err(|e| layout_err(path, format!("starting the H.264 decoder: {e}")))?;
        Ok(Self {
            file,
            decoder,
            next_sample: 0,
            pictures: VecDeque::new(),
            next_picture: 0,
            ended: None,
        })
    }
}

fn to_rgb(pic: &DecodedYUV<'_>) -> Rgb8 {
    let (w, h) = pic.dimensions();
    let mut buf = vec![0u8; w * h * 3];
    pic.write_rgb8(&mut buf);
    let data = buf.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
    Rgb8 {
        width: w,
        height: h,
        data,
    }
}

/// Frames per second from the median interval of the stamps (`None` with fewer than two).
fn frame_rate(stamps: &[f64]) -> Option<f64> {
    let mut dt: Vec<f64> = stamps
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .collect();
    if dt.is_empty() {
        return None;
    }
    dt.sort_by(f64::total_cmp);
    let fps = 1.0 / dt[dt.len() / 2];
    // 29.97 stays 29.97; 30.000001 becomes 30.
    let rounded = (fps * 1000.0).round() / 1000.0;
    (rounded > 0.0).then_some(rounded)
}

impl Sequence for VideoSequence {
    fn settings(&self) -> &Settings {
        &self.settings
    }
    fn len(&self) -> usize {
        self.stamps.len()
    }
    fn frame(&self, i: usize) -> Result<Frame, DatasetError> {
        check_index(i, self.stamps.len())?;
        let rgb = self.picture(i)?;
        let c = &self.settings.camera;
        if (rgb.width, rgb.height) != (c.width as usize, c.height as usize) {
            return Err(DatasetError::SizeMismatch {
                path: format!("{}: frame {i}", self.path.display()),
                width: rgb.width,
                height: rgb.height,
                expected_width: c.width,
                expected_height: c.height,
            });
        }
        Ok(Frame {
            index: i,
            timestamp: self.stamps[i],
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
        None
    }
    fn name(&self) -> String {
        self.path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.path.display().to_string())
    }
    fn timestamp(&self, i: usize) -> Option<f64> {
        self.stamps.get(i).copied()
    }
}
