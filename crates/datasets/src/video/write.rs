//! Frames written as an H.264 MP4 (openh264's encoder, the `mp4` crate's muxer): what `run
//! --video` reads, for tests and for turning an image sequence into a clip.

use crate::error::{DatasetError, io_err, recording_err};
use openh264::encoder::{BitRate, Encoder, EncoderConfig, FrameRate};
use openh264::formats::{RgbSliceU8, YUVBuffer};
use std::io::Cursor;
use std::path::{Path, PathBuf};
use stillpoint_image::Rgb8;

/// Ticks per second of the written sample times (90 kHz, as MPEG streams count).
const TIMESCALE: u32 = 90_000;

/// Encodes RGB frames into an MP4 file, written whole by [`VideoWriter::finish`].
pub struct VideoWriter {
    path: PathBuf,
    encoder: Encoder,
    mux: ::mp4::Mp4Writer<Cursor<Vec<u8>>>,
    track_added: bool,
    size: (usize, usize),
    /// Ticks per frame.
    duration: u32,
    frames: u64,
    faststart: bool,
}

/// How a clip is written.
#[derive(Clone, Copy, Debug)]
pub struct VideoOptions {
    /// Frames per second.
    pub fps: f64,
    /// Target bit rate, bits per second (a high one keeps the frames close to the images).
    pub bitrate: u32,
    /// The sample index (`moov`) before the samples, as `ffmpeg -movflags +faststart` writes it
    /// (streamable; a cut file keeps its first frames); else after them, as recorders write it.
    pub faststart: bool,
}

impl Default for VideoOptions {
    fn default() -> Self {
        Self {
            fps: 30.0,
            bitrate: 8_000_000,
            faststart: false,
        }
    }
}

impl VideoWriter {
    /// A writer of `width` x `height` frames to `path`.
    pub fn create(
        path: &Path,
        width: usize,
        height: usize,
        options: VideoOptions,
    ) -> Result<Self, DatasetError> {
        let err = |m: String| recording_err(path, "writing", m);
        if !width.is_multiple_of(2) || !height.is_multiple_of(2) || width == 0 || height == 0 {
            return Err(err(format!(
                "{width}x{height}: H.264 4:2:0 needs an even, non-zero width and height"
            )));
        }
        let config = EncoderConfig::new()
            .bitrate(BitRate::from_bps(options.bitrate))
            .max_frame_rate(FrameRate::from_hz(options.fps as f32))
            .skip_frames(false);
        let encoder = Encoder::with_api_config(openh264::OpenH264API::from_source(), config)
            .map_err(|e| err(format!("starting the H.264 encoder: {e}")))?;
        let brand = |s: &str| s.parse::<::mp4::FourCC>();
        let config = ::mp4::Mp4Config {
            major_brand: brand("isom").map_err(|e| err(e.to_string()))?,
            minor_version: 512,
            compatible_brands: ["isom", "iso2", "avc1", "mp41"]
                .iter()
                .map(|b| brand(b))
                .collect::<Result<_, _>>()
                .map_err(|e| err(e.to_string()))?,
            timescale: 1000,
        };
        let mux = ::mp4::Mp4Writer::write_start(Cursor::new(Vec::new()), &config)
            .map_err(|e| err(e.to_string()))?;
        Ok(Self {
            path: path.to_path_buf(),
            encoder,
            mux,
            track_added: false,
            size: (width, height),
            duration: (f64::from(TIMESCALE) / options.fps).round() as u32,
            frames: 0,
            faststart: options.faststart,
        })
    }

    fn err(&self, m: impl Into<String>) -> DatasetError {
        recording_err(&self.path, format!("writing frame {}", self.frames), m)
    }

    /// Encode and add one frame.
    pub fn write(&mut self, rgb: &Rgb8) -> Result<(), DatasetError> {
        if (rgb.width, rgb.height) != self.size {
            return Err(self.err(format!(
                "a {}x{} frame in a {}x{} video",
                rgb.width, rgb.height, self.size.0, self.size.1
            )));
        }
        let flat: Vec<u8> = rgb.data.iter().flatten().copied().collect();
        let yuv = YUVBuffer::from_rgb8_source(RgbSliceU8::new(&flat, self.size));
        let stream = self
            .encoder
            .encode(&yuv)
            .map_err(|e| recording_err(&self.path, "writing", e.to_string()))?
            .to_vec();
        let mut parameter_sets: Vec<&[u8]> = Vec::new();
        let mut sample = Vec::with_capacity(stream.len());
        let mut sync = false;
        for nal in split_annex_b(&stream) {
            match nal.first().map(|b| b & 0x1f) {
                Some(7 | 8) => parameter_sets.push(nal),
                Some(t) => {
                    sync |= t == 5;
                    sample.extend_from_slice(&(nal.len() as u32).to_be_bytes());
                    sample.extend_from_slice(nal);
                }
                None => {}
            }
        }
        if !self.track_added {
            let (Some(sps), Some(pps)) = (
                parameter_sets.iter().find(|n| n[0] & 0x1f == 7),
                parameter_sets.iter().find(|n| n[0] & 0x1f == 8),
            ) else {
                return Err(self.err("the encoder's first frame has no SPS / PPS"));
            };
            let track = ::mp4::TrackConfig {
                track_type: ::mp4::TrackType::Video,
                timescale: TIMESCALE,
                language: "und".into(),
                media_conf: ::mp4::MediaConfig::AvcConfig(::mp4::AvcConfig {
                    width: self.size.0 as u16,
                    height: self.size.1 as u16,
                    seq_param_set: sps.to_vec(),
                    pic_param_set: pps.to_vec(),
                }),
            };
            let r = self.mux.add_track(&track);
            r.map_err(|e| self.err(e.to_string()))?;
            self.track_added = true;
        }
        let sample = ::mp4::Mp4Sample {
            start_time: self.frames * u64::from(self.duration),
            duration: self.duration,
            rendering_offset: 0,
            is_sync: sync,
            bytes: sample.into(),
        };
        let r = self.mux.write_sample(1, &sample);
        r.map_err(|e| self.err(e.to_string()))?;
        self.frames += 1;
        Ok(())
    }

    /// Write the sample index and the file.
    pub fn finish(mut self) -> Result<(), DatasetError> {
        if !self.track_added {
            return Err(self.err("no frame was written"));
        }
        let r = self.mux.write_end();
        r.map_err(|e| self.err(e.to_string()))?;
        let mut bytes = self.mux.into_writer().into_inner();
        if self.faststart {
            bytes = moov_first(&bytes).map_err(|m| recording_err(&self.path, "writing", m))?;
        }
        std::fs::write(&self.path, bytes).map_err(io_err(&self.path))
    }
}

/// The NAL units of an Annex B stream (start codes and trailing zeros removed).
fn split_annex_b(s: &[u8]) -> Vec<&[u8]> {
    let mut starts = Vec::new();
    let mut i = 0;
    while i + 3 <= s.len() {
        if s[i] == 0 && s[i + 1] == 0 && s[i + 2] == 1 {
            starts.push(i + 3);
            i += 3;
        } else {
            i += 1;
        }
    }
    starts
        .iter()
        .enumerate()
        .map(|(k, &a)| {
            let mut b = starts.get(k + 1).map_or(s.len(), |&n| n - 3);
            while b > a && s[b - 1] == 0 {
                b -= 1;
            }
            &s[a..b]
        })
        .filter(|n| !n.is_empty())
        .collect()
}

/// The file with its `moov` box moved before `mdat`, the chunk offsets (`stco` / `co64`)
/// shifted by the moov's size.
fn moov_first(file: &[u8]) -> Result<Vec<u8>, String> {
    let mut top = Vec::new();
    let mut pos = 0usize;
    while pos + 8 <= file.len() {
        let size = u32::from_be_bytes(file[pos..pos + 4].try_into().unwrap_or_default()) as usize;
        if size < 8 || pos + size > file.len() {
            return Err(format!("box at byte {pos}: 64-bit or bad size"));
        }
        top.push((&file[pos + 4..pos + 8], pos, size));
        pos += size;
    }
    let find = |k: &[u8]| top.iter().find(|(t, _, _)| *t == k).copied();
    let (Some(ftyp), Some(moov)) = (find(b"ftyp"), find(b"moov")) else {
        return Err("no ftyp or moov box".into());
    };
    let mut moov_bytes = file[moov.1..moov.1 + moov.2].to_vec();
    shift_chunk_offsets(&mut moov_bytes, 8, moov.2 as u64)?;
    let mut out = file[ftyp.1..ftyp.1 + ftyp.2].to_vec();
    out.extend_from_slice(&moov_bytes);
    for (kind, at, size) in &top {
        if *kind != b"ftyp" && *kind != b"moov" {
            out.extend_from_slice(&file[*at..at + size]);
        }
    }
    Ok(out)
}

/// Add `by` to every chunk offset in the boxes inside `b[from..]` (a container's children).
fn shift_chunk_offsets(b: &mut [u8], from: usize, by: u64) -> Result<(), String> {
    let mut pos = from;
    while pos + 8 <= b.len() {
        let size = u32::from_be_bytes(b[pos..pos + 4].try_into().unwrap_or_default()) as usize;
        if size < 8 || pos + size > b.len() {
            return Err(format!("moov: a box of {size} bytes at {pos}"));
        }
        let kind: [u8; 4] = b[pos + 4..pos + 8].try_into().unwrap_or_default();
        let body = &mut b[pos..pos + size];
        match &kind {
            b"trak" | b"mdia" | b"minf" | b"stbl" => shift_chunk_offsets(body, 8, by)?,
            b"stco" | b"co64" => {
                let wide = &kind == b"co64";
                let n = u32::from_be_bytes(body[12..16].try_into().unwrap_or_default()) as usize;
                let w = if wide { 8 } else { 4 };
                if 16 + n * w > body.len() {
                    return Err("moov: a short chunk offset table".into());
                }
                for e in 0..n {
                    let at = 16 + e * w;
                    if wide {
                        let v = u64::from_be_bytes(body[at..at + 8].try_into().unwrap_or_default());
                        body[at..at + 8].copy_from_slice(&(v + by).to_be_bytes());
                    } else {
                        let v = u32::from_be_bytes(body[at..at + 4].try_into().unwrap_or_default());
                        let v = u32::try_from(u64::from(v) + by)
                            .map_err(|_| "moov: an offset past 4 GiB".to_string())?;
                        body[at..at + 4].copy_from_slice(&v.to_be_bytes());
                    }
                }
            }
            _ => {}
        }
        pos += size;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A moving pattern: bars that slide one pixel a frame over a gradient.
    fn pattern(w: usize, h: usize, t: usize) -> Rgb8 {
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let bar = if ((x + t) / 8).is_multiple_of(2) {
                    200
                } else {
                    40
                };
                [bar, (y * 255 / h) as u8, ((x * 255) / w) as u8]
            })
            .collect();
        Rgb8 {
            width: w,
            height: h,
            data,
        }
    }

    fn write_clip(path: &Path, frames: usize, faststart: bool) -> Vec<Rgb8> {
        let opts = VideoOptions {
            fps: 25.0,
            faststart,
            ..Default::default()
        };
        let mut w = VideoWriter::create(path, 64, 48, opts).unwrap();
        let images: Vec<Rgb8> = (0..frames).map(|t| pattern(64, 48, t)).collect();
        for im in &images {
            w.write(im).unwrap();
        }
        w.finish().unwrap();
        images
    }

    fn mean_abs_diff(a: &Rgb8, b: &Rgb8) -> f64 {
        let s: u64 = a
            .data
            .iter()
            .flatten()
            .zip(b.data.iter().flatten())
            .map(|(x, y)| u64::from(x.abs_diff(*y)))
            .sum();
        s as f64 / (a.data.len() * 3) as f64
    }

    #[test]
    fn a_written_clip_reads_back_frame_by_frame() {
        let tmp = tempfile::tempdir().unwrap();
        for faststart in [false, true] {
            let p = tmp.path().join(format!("clip{faststart}.mp4"));
            let images = write_clip(&p, 12, faststart);
            let seq = crate::video::open(&p, None).unwrap();
            assert_eq!(seq.len(), 12);
            assert_eq!(seq.settings().fps, 25.0);
            assert_eq!(seq.settings().sensor, crate::Sensor::Mono);
            assert_eq!(
                (seq.settings().camera.width, seq.settings().camera.height),
                (64, 48)
            );
            for (i, im) in images.iter().enumerate() {
                let f = seq.frame(i).unwrap();
                assert_eq!(f.timestamp, i as f64 * 0.04, "frame {i}");
                let d = mean_abs_diff(f.rgb.as_ref().unwrap(), im);
                assert!(d < 12.0, "frame {i}: mean difference {d}");
            }
            // Backwards: decoding starts again.
            let again = seq.frame(3).unwrap();
            assert!(mean_abs_diff(again.rgb.as_ref().unwrap(), &images[3]) < 12.0);
            assert!(matches!(
                seq.frame(12),
                Err(DatasetError::OutOfRange { index: 12, len: 12 })
            ));
        }
    }

    #[test]
    fn a_cut_clip_keeps_its_first_frames_or_names_the_missing_index() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("fast.mp4");
        write_clip(&p, 10, true);
        let bytes = std::fs::read(&p).unwrap();
        let cut = tmp.path().join("cut.mp4");
        std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
        let seq = crate::video::open(&cut, None).unwrap();
        assert_eq!(seq.len(), 10);
        let mut read = 0;
        let err = loop {
            match seq.frame(read) {
                Ok(_) => read += 1,
                Err(e) => break e,
            }
        };
        assert!((1..10).contains(&read), "{read} frames");
        let DatasetError::Ended {
            ref path,
            ref at,
            ref msg,
        } = err
        else {
            panic!("{err}");
        };
        assert_eq!(path, &cut.display().to_string());
        assert!(at.starts_with(&format!("sample {read} (byte ")), "{err}");
        assert!(msg.contains("cut short"), "{err}");

        // Recorders write the index last: cut, nothing can be found.
        let p = tmp.path().join("slow.mp4");
        write_clip(&p, 10, false);
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&cut, &bytes[..bytes.len() - 100]).unwrap();
        let e = crate::video::open(&cut, None).err().unwrap().to_string();
        assert!(
            e.starts_with(&format!("{}: byte {}: ", cut.display(), bytes.len() - 100)),
            "{e}"
        );
        assert!(e.contains("no moov box"), "{e}");
    }

    #[test]
    fn annex_b_splits_on_three_and_four_byte_start_codes() {
        let s = [
            0, 0, 0, 1, 0x67, 1, 2, 0, 0, 1, 0x68, 3, 0, 0, 0, 1, 0x65, 4,
        ];
        assert_eq!(
            split_annex_b(&s),
            vec![&[0x67, 1, 2][..], &[0x68, 3][..], &[0x65, 4][..]]
        );
    }
}
