//! The MP4 container: the top-level boxes walked by hand (so a cut file names its byte), the
//! `moov` box parsed by the `mp4` crate, and the H.264 track's sample table (where each sample
//! lies, its times, whether it is a sync sample) computed from it.

use crate::error::{DatasetError, io_err, recording_err};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

/// A top-level box.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TopBox {
    /// Four-character type.
    pub kind: [u8; 4],
    /// Byte offset of its header.
    pub offset: u64,
    /// Size with the header.
    pub size: u64,
}

impl TopBox {
    fn name(&self) -> String {
        String::from_utf8_lossy(&self.kind).into_owned()
    }
}

/// One sample (an access unit: one picture's NAL units) of the video track.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Byte offset in the file.
    pub offset: u64,
    /// Bytes.
    pub size: u32,
    /// Composition (presentation) time, track timescale units.
    pub composition: i64,
    /// A sync sample (IDR picture): decoding can start here.
    pub sync: bool,
}

/// The H.264 track of a file.
#[derive(Clone, Debug)]
pub struct Track {
    /// Samples in decoding order.
    pub samples: Vec<Sample>,
    /// Ticks per second of the sample times.
    pub timescale: u32,
    /// Sequence and picture parameter sets (without start codes).
    pub parameter_sets: Vec<Vec<u8>>,
    /// Bytes of each NAL unit's length prefix in the samples (1, 2 or 4).
    pub length_size: usize,
    /// The file's size.
    pub file_len: u64,
}

/// The boxes at the top of the file, up to its end or the first box that runs past it (that one
/// is returned as the cut box).
pub fn top_boxes(
    path: &Path,
    r: &mut (impl Read + Seek),
    len: u64,
) -> Result<(Vec<TopBox>, Option<TopBox>), DatasetError> {
    let mut boxes = Vec::new();
    let mut pos = 0u64;
    while pos < len {
        let at = |m: String| recording_err(path, format!("byte {pos}"), m);
        if len - pos < 8 {
            return Err(at(format!(
                "a box header needs 8 bytes, {} are left: the file is cut short",
                len - pos
            )));
        }
        r.seek(SeekFrom::Start(pos)).map_err(io_err(path))?;
        let mut head = [0u8; 16];
        let n = if len - pos >= 16 { 16 } else { 8 };
        r.read_exact(&mut head[..n]).map_err(io_err(path))?;
        let size32 = u32::from_be_bytes([head[0], head[1], head[2], head[3]]);
        let kind = [head[4], head[5], head[6], head[7]];
        let size = match size32 {
            0 => len - pos,
            1 if n == 16 => u64::from_be_bytes(head[8..16].try_into().unwrap_or_default()),
            1 => return Err(at("a 64-bit box size past the end of the file".into())),
            s => u64::from(s),
        };
        let b = TopBox {
            kind,
            offset: pos,
            size,
        };
        if size < 8 {
            return Err(at(format!(
                "a {:?} box of {size} bytes, shorter than its header: not an MP4 file, or corrupt",
                b.name()
            )));
        }
        if pos == 0 && head[..4] == [0x1a, 0x45, 0xdf, 0xa3] {
            return Err(at(
                "a Matroska / WebM file (.mkv): not read; remux it to MP4 without re-encoding: \
                 ffmpeg -i IN.mkv -c copy OUT.mp4"
                    .into(),
            ));
        }
        if pos == 0 && !kind.iter().all(|c| c.is_ascii_alphanumeric() || *c == b' ') {
            return Err(at(format!(
                "not an MP4 file (it starts with {:02x?}; an MP4 starts with a box size and a type such as `ftyp`)",
                &head[..8]
            )));
        }
        if size > len - pos {
            return Ok((boxes, Some(b)));
        }
        boxes.push(b);
        pos += size;
    }
    Ok((boxes, None))
}

/// Read the file's box layout and its H.264 track's sample table.
pub fn read_track(path: &Path) -> Result<Track, DatasetError> {
    let file = File::open(path).map_err(io_err(path))?;
    let len = file.metadata().map_err(io_err(path))?.len();
    let mut r = BufReader::new(file);
    let (boxes, cut) = top_boxes(path, &mut r, len)?;
    let Some(moov) = boxes.iter().find(|b| &b.kind == b"moov") else {
        let why = match cut {
            Some(c) => format!(
                "the file ends inside its {:?} box (byte {} of {} declared) and has no moov box \
                 (the sample index, which recorders write last): it was cut short, and nothing in \
                 it can be located",
                c.name(),
                len - c.offset,
                c.size
            ),
            None => "no moov box (the sample index): not a complete MP4 file".into(),
        };
        return Err(recording_err(path, format!("byte {len}"), why));
    };
    r.seek(SeekFrom::Start(moov.offset)).map_err(io_err(path))?;
    let at = format!("byte {} (moov box)", moov.offset);
    let header =
        ::mp4::BoxHeader::read(&mut r).map_err(|e| recording_err(path, &at, e.to_string()))?;
    let parsed = <::mp4::MoovBox as ::mp4::ReadBox<_>>::read_box(&mut r, header.size)
        .map_err(|e| recording_err(path, &at, e.to_string()))?;
    let t = parsed
        .traks
        .iter()
        .position(|t| t.mdia.minf.stbl.stsd.avc1.is_some())
        .ok_or_else(|| {
            let kinds: Vec<String> = parsed
                .traks
                .iter()
                .map(|t| {
                    let s = &t.mdia.minf.stbl.stsd;
                    if s.hev1.is_some() {
                        "H.265 video".into()
                    } else if s.vp09.is_some() {
                        "VP9 video".into()
                    } else if s.mp4a.is_some() {
                        "AAC audio".into()
                    } else {
                        t.mdia.hdlr.handler_type.to_string()
                    }
                })
                .collect();
            recording_err(
                path,
                &at,
                format!(
                    "no H.264 (avc1) video track (tracks: {}); re-encode it: ffmpeg -i IN -c:v libx264 OUT.mp4",
                    if kinds.is_empty() { "none".into() } else { kinds.join(", ") }
                ),
            )
        })?;
    let trak = &parsed.traks[t];
    let stbl = &trak.mdia.minf.stbl;
    let avcc = &stbl.stsd.avc1.as_ref().map(|a| &a.avcc);
    let Some(avcc) = avcc else {
        return Err(recording_err(path, &at, "no avcC box"));
    };
    let length_size = usize::from(avcc.length_size_minus_one & 3) + 1;
    if length_size == 3 {
        return Err(recording_err(
            path,
            &at,
            "avcC: NAL length size 3 is not valid",
        ));
    }
    let parameter_sets = avcc
        .sequence_parameter_sets
        .iter()
        .chain(&avcc.picture_parameter_sets)
        .map(|n| n.bytes.clone())
        .collect();
    let timescale = trak.mdia.mdhd.timescale;
    if timescale == 0 {
        return Err(recording_err(path, &at, "mdhd: timescale 0"));
    }
    let samples = sample_table(&parsed, t).map_err(|m| recording_err(path, &at, m))?;
    if samples.is_empty() {
        return Err(recording_err(path, &at, "the video track has no samples"));
    }
    Ok(Track {
        samples,
        timescale,
        parameter_sets,
        length_size,
        file_len: len,
    })
}

/// Where each sample lies and when it is shown, from `stsz`, `stsc`, `stco`/`co64`, `stts`,
/// `ctts` and `stss`. A table that contradicts itself is an error naming the box.
fn sample_table(moov: &::mp4::MoovBox, track: usize) -> Result<Vec<Sample>, String> {
    let stbl = &moov.traks[track].mdia.minf.stbl;
    let stsz = &stbl.stsz;
    let count = stsz.sample_count as usize;
    let size_of = |i: usize| -> Result<u32, String> {
        if stsz.sample_size != 0 {
            Ok(stsz.sample_size)
        } else {
            stsz.sample_sizes.get(i).copied().ok_or_else(|| {
                format!(
                    "stsz: {count} samples but {} sizes",
                    stsz.sample_sizes.len()
                )
            })
        }
    };
    let chunks: Vec<u64> = match (&stbl.stco, &stbl.co64) {
        (Some(s), _) => s.entries.iter().map(|&o| u64::from(o)).collect(),
        (None, Some(c)) => c.entries.clone(),
        (None, None) => return Err("no stco or co64 box (chunk offsets)".into()),
    };
    let stsc = &stbl.stsc.entries;
    if stsc.is_empty() && count > 0 {
        return Err("stsc: no entries".into());
    }
    let mut offsets = Vec::with_capacity(count);
    let mut sizes = Vec::with_capacity(count);
    'chunks: for (c, &chunk_offset) in chunks.iter().enumerate() {
        let chunk = c as u32 + 1;
        let per_chunk = stsc
            .iter()
            .rev()
            .find(|e| e.first_chunk <= chunk)
            .map_or(0, |e| e.samples_per_chunk);
        let mut at = chunk_offset;
        for _ in 0..per_chunk {
            if offsets.len() == count {
                break 'chunks;
            }
            let size = size_of(offsets.len())?;
            offsets.push(at);
            sizes.push(size);
            at += u64::from(size);
        }
    }
    if offsets.len() < count {
        return Err(format!(
            "stsc/stco: {} chunks hold {} samples but stsz has {count}",
            chunks.len(),
            offsets.len()
        ));
    }
    let mut decode_times = Vec::with_capacity(count);
    let mut t = 0i64;
    for e in &stbl.stts.entries {
        for _ in 0..e.sample_count {
            if decode_times.len() == count {
                break;
            }
            decode_times.push(t);
            t += i64::from(e.sample_delta);
        }
    }
    if decode_times.len() < count {
        return Err(format!(
            "stts: times for {} samples, stsz has {count}",
            decode_times.len()
        ));
    }
    let mut shifts = vec![0i64; count];
    if let Some(ctts) = &stbl.ctts {
        let mut i = 0usize;
        for e in &ctts.entries {
            for _ in 0..e.sample_count {
                if i < count {
                    shifts[i] = i64::from(e.sample_offset);
                    i += 1;
                }
            }
        }
    }
    let sync: Option<std::collections::BTreeSet<u32>> = stbl
        .stss
        .as_ref()
        .map(|s| s.entries.iter().copied().collect());
    Ok((0..count)
        .map(|i| Sample {
            offset: offsets[i],
            size: sizes[i],
            composition: decode_times[i] + shifts[i],
            sync: sync.as_ref().is_none_or(|s| s.contains(&(i as u32 + 1))),
        })
        .collect())
}

/// A sample's NAL units (length-prefixed, as MP4 holds them) as an Annex B byte stream
/// (start codes), which the decoder reads.
pub fn to_annex_b(sample: &[u8], length_size: usize, out: &mut Vec<u8>) -> Result<(), String> {
    let mut pos = 0;
    while pos < sample.len() {
        if sample.len() - pos < length_size {
            return Err(format!(
                "a NAL length at byte {pos} of the sample runs past its end"
            ));
        }
        let n = sample[pos..pos + length_size]
            .iter()
            .fold(0usize, |a, &b| (a << 8) | usize::from(b));
        pos += length_size;
        if n > sample.len() - pos {
            return Err(format!(
                "a NAL unit of {n} bytes at byte {pos} of the sample, which has {} left: corrupt",
                sample.len() - pos
            ));
        }
        out.extend_from_slice(&[0, 0, 0, 1]);
        out.extend_from_slice(&sample[pos..pos + n]);
        pos += n;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn length_prefixed_nals_become_start_codes() {
        let mut out = Vec::new();
        to_annex_b(&[0, 0, 0, 2, 0x65, 1, 0, 0, 0, 1, 0x41], 4, &mut out).unwrap();
        assert_eq!(out, [0, 0, 0, 1, 0x65, 1, 0, 0, 0, 1, 0x41]);
        let e = to_annex_b(&[0, 0, 0, 9, 0x65], 4, &mut Vec::new()).unwrap_err();
        assert!(e.contains("9 bytes at byte 4"), "{e}");
    }

    #[test]
    fn a_file_that_is_no_mp4_says_so() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("x.mp4");
        std::fs::write(&p, b"RIFF\0\0\0\0AVI LIST").unwrap();
        let e = read_track(&p).unwrap_err().to_string();
        assert!(
            e.contains("byte 0: ") && e.contains("not an MP4 file"),
            "{e}"
        );
    }
}
