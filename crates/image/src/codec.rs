//! PNG and JPEG bytes to samples and back, on the `png` and `zune-jpeg` crates directly.
//!
//! These are the decoders the `image` crate runs for the two formats, with its options (PNG:
//! palettes and low bit depths expanded, 16-bit samples kept; JPEG: lenient, RGB unless the
//! file is gray), so the samples are the same; its colour conversions are [`Decoded::to_rgb8`].
//! Without `image` a cold build compiles ~70 crate-seconds less.
//!
//! ```
//! use stillpoint_image::{Rgb8, codec, encode_png};
//! let img = Rgb8::from_vec(2, 1, vec![[255, 0, 0], [0, 0, 255]]).unwrap();
//! let decoded = codec::decode(&encode_png(&img).unwrap()).unwrap();
//! assert_eq!((decoded.width, decoded.height, decoded.channels), (2, 1, 3));
//! assert_eq!(decoded.to_rgb8(), img);
//! ```

use crate::{Gray8, ImageBuf, Rgb8, luma};

/// The most memory one decoded image may take, as `image`'s default limit: a small file can
/// declare a huge image.
pub const MAX_DECODED_BYTES: usize = 512 << 20;

/// The file formats read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// PNG.
    Png,
    /// JPEG.
    Jpeg,
}

/// The format from the file's first bytes.
pub fn format_of(bytes: &[u8]) -> Option<Format> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some(Format::Png)
    } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some(Format::Jpeg)
    } else {
        None
    }
}

/// A JPEG without its end-of-image marker: cut short (a file still being written, a full
/// disk). It still decodes (leniently, as `image` and libjpeg do), the part its data does not
/// reach filled in by the decoder, so the caller says so.
pub fn jpeg_truncated(bytes: &[u8]) -> bool {
    format_of(bytes) == Some(Format::Jpeg) && !bytes.windows(2).rev().any(|w| w == [0xFF, 0xD9])
}

/// Why bytes did not decode.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// Neither signature.
    #[error("neither a PNG nor a JPEG file")]
    UnknownFormat,
    /// The PNG decoder's error.
    #[error("PNG: {0}")]
    Png(#[from] png::DecodingError),
    /// The JPEG decoder's error.
    #[error("JPEG: {0}")]
    Jpeg(String),
    /// Samples of a kind not read (a PNG of more than 16 bits, say).
    #[error("{0}: not supported")]
    Unsupported(String),
    /// More than [`MAX_DECODED_BYTES`].
    #[error("a {width}x{height} image of {channels} channels is over the {} MiB decoding limit", MAX_DECODED_BYTES >> 20)]
    TooLarge {
        /// Declared columns.
        width: usize,
        /// Declared rows.
        height: usize,
        /// Channels.
        channels: usize,
    },
}

/// A decoded image's samples.
#[derive(Clone, Debug, PartialEq)]
pub enum Samples {
    /// 8 bits a sample.
    U8(Vec<u8>),
    /// 16 bits a sample (PNG only), in native order.
    U16(Vec<u16>),
}

/// A decoded image: `width * height * channels` samples, pixel after pixel, row after row.
#[derive(Clone, Debug, PartialEq)]
pub struct Decoded {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// 1 gray, 2 gray and alpha, 3 RGB, 4 RGBA.
    pub channels: usize,
    /// The samples.
    pub samples: Samples,
}

/// Decode a PNG or JPEG file's bytes.
pub fn decode(bytes: &[u8]) -> Result<Decoded, DecodeError> {
    match format_of(bytes) {
        Some(Format::Png) => decode_png(bytes),
        Some(Format::Jpeg) => decode_jpeg(bytes),
        None => Err(DecodeError::UnknownFormat),
    }
}

/// Width and height from the header alone (no limit: a huge image can be sized).
pub fn dimensions(bytes: &[u8]) -> Result<(usize, usize), DecodeError> {
    match format_of(bytes) {
        Some(Format::Png) => {
            let mut d = png::Decoder::new(std::io::Cursor::new(bytes));
            let info = d.read_header_info()?;
            Ok((info.width as usize, info.height as usize))
        }
        Some(Format::Jpeg) => {
            let mut d = jpeg_decoder(bytes, None);
            d.decode_headers().map_err(jpeg_err)?;
            d.dimensions()
                .ok_or_else(|| DecodeError::Jpeg("no frame header".into()))
        }
        None => Err(DecodeError::UnknownFormat),
    }
}

/// Width and height from a file's header, reading only its first 64 KiB unless the header
/// lies further in (a JPEG with large metadata segments): frames are sized before they are
/// decoded, and reading them whole twice would double the IO a frame.
pub fn file_dimensions(path: &std::path::Path) -> std::io::Result<Option<(usize, usize)>> {
    use std::io::Read;
    const PREFIX: u64 = 64 << 10;
    let mut file = std::fs::File::open(path)?;
    let mut head = Vec::new();
    (&mut file).take(PREFIX).read_to_end(&mut head)?;
    if let Ok(size) = dimensions(&head) {
        return Ok(Some(size));
    }
    if (head.len() as u64) < PREFIX {
        return Ok(None);
    }
    file.read_to_end(&mut head)?;
    Ok(dimensions(&head).ok())
}

fn check_size(
    width: usize,
    height: usize,
    channels: usize,
    bytes_per_sample: usize,
) -> Result<usize, DecodeError> {
    let too_large = || DecodeError::TooLarge {
        width,
        height,
        channels,
    };
    let n = width
        .checked_mul(height)
        .and_then(|p| p.checked_mul(channels))
        .ok_or_else(too_large)?;
    if n.saturating_mul(bytes_per_sample) > MAX_DECODED_BYTES {
        return Err(too_large());
    }
    Ok(n)
}

fn decode_png(bytes: &[u8]) -> Result<Decoded, DecodeError> {
    let mut d = png::Decoder::new_with_limits(
        std::io::Cursor::new(bytes),
        png::Limits {
            bytes: MAX_DECODED_BYTES,
        },
    );
    // As `image`: palettes, low bit depths and tRNS expanded; 16-bit samples kept.
    d.set_transformations(png::Transformations::EXPAND);
    let mut reader = d.read_info()?;
    let (color, depth) = reader.output_color_type();
    let channels = match color {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => return Err(DecodeError::Unsupported("indexed PNG".into())),
    };
    let bytes_per_sample = match depth {
        png::BitDepth::Eight => 1,
        png::BitDepth::Sixteen => 2,
        other => return Err(DecodeError::Unsupported(format!("{other:?}-bit PNG"))),
    };
    let info = reader.info();
    let (width, height) = (info.width as usize, info.height as usize);
    let n = check_size(width, height, channels, bytes_per_sample)?;
    let mut buf = vec![0u8; n * bytes_per_sample];
    reader.next_frame(&mut buf)?;
    let samples = if bytes_per_sample == 1 {
        Samples::U8(buf)
    } else {
        Samples::U16(
            buf.chunks_exact(2)
                .map(|c| u16::from_be_bytes([c[0], c[1]]))
                .collect(),
        )
    };
    Ok(Decoded {
        width,
        height,
        channels,
        samples,
    })
}

type JpegDecoder<'a> = zune_jpeg::JpegDecoder<zune_core::bytestream::ZCursor<&'a [u8]>>;

/// `image`'s options: lenient, no size limit of the decoder's own (ours is in bytes).
fn jpeg_decoder(bytes: &[u8], out: Option<zune_core::colorspace::ColorSpace>) -> JpegDecoder<'_> {
    let mut options = zune_core::options::DecoderOptions::default()
        .set_strict_mode(false)
        .set_max_width(usize::MAX)
        .set_max_height(usize::MAX);
    if let Some(out) = out {
        options = options.jpeg_set_out_colorspace(out);
    }
    zune_jpeg::JpegDecoder::new_with_options(zune_core::bytestream::ZCursor::new(bytes), options)
}

fn jpeg_err(e: zune_jpeg::errors::DecodeErrors) -> DecodeError {
    DecodeError::Jpeg(e.to_string())
}

fn decode_jpeg(bytes: &[u8]) -> Result<Decoded, DecodeError> {
    use zune_core::colorspace::ColorSpace;
    let mut d = jpeg_decoder(bytes, None);
    d.decode_headers().map_err(jpeg_err)?;
    let (width, height) = d
        .dimensions()
        .ok_or_else(|| DecodeError::Jpeg("no frame header".into()))?;
    // Gray stays gray; YCbCr, CMYK and the rest become RGB, as in `image`.
    let out = match d.input_colorspace() {
        Some(c @ (ColorSpace::RGB | ColorSpace::RGBA | ColorSpace::Luma | ColorSpace::LumaA)) => c,
        _ => ColorSpace::RGB,
    };
    let channels = out.num_components();
    let n = check_size(width, height, channels, 1)?;
    let mut d = jpeg_decoder(bytes, Some(out));
    let mut buf = vec![0u8; n];
    d.decode_into(&mut buf).map_err(jpeg_err)?;
    Ok(Decoded {
        width,
        height,
        channels,
        samples: Samples::U8(buf),
    })
}

/// `image`'s 16- to 8-bit rounding.
fn to_u8(v: u16) -> u8 {
    ((u32::from(v) + 128) / 257) as u8
}

impl Decoded {
    /// The colour type as `image` names it (`L8`, `Rgb8`, `La16`...), for error messages.
    pub fn color_name(&self) -> &'static str {
        let sixteen = matches!(self.samples, Samples::U16(_));
        match (self.channels, sixteen) {
            (1, false) => "L8",
            (2, false) => "La8",
            (3, false) => "Rgb8",
            (4, false) => "Rgba8",
            (1, true) => "L16",
            (2, true) => "La16",
            (3, true) => "Rgb16",
            _ => "Rgba16",
        }
    }

    /// 8-bit RGB: gray replicated, alpha dropped, 16-bit samples rounded down to 8.
    pub fn to_rgb8(&self) -> Rgb8 {
        let c = self.channels;
        let pixel = |s: &[u8]| match c {
            1 | 2 => [s[0]; 3],
            _ => [s[0], s[1], s[2]],
        };
        let data = match &self.samples {
            Samples::U8(v) => v.chunks_exact(c).map(pixel).collect(),
            Samples::U16(v) => {
                let v8: Vec<u8> = v.iter().map(|&x| to_u8(x)).collect();
                v8.chunks_exact(c).map(pixel).collect()
            }
        };
        ImageBuf {
            width: self.width,
            height: self.height,
            data,
        }
    }

    /// 8-bit gray: an 8-bit gray image as it is, anything else through [`Decoded::to_rgb8`]
    /// and [`luma`].
    pub fn to_gray8(self) -> Gray8 {
        if self.channels == 1
            && let Samples::U8(data) = self.samples
        {
            return ImageBuf {
                width: self.width,
                height: self.height,
                data,
            };
        }
        let rgb = self.to_rgb8();
        ImageBuf {
            width: rgb.width,
            height: rgb.height,
            data: rgb.data.iter().map(|&p| luma(p)).collect(),
        }
    }

    /// The raw values of a 16-bit single-channel image; `Err(self)` for anything else.
    pub fn into_gray16(self) -> Result<ImageBuf<u16>, Self> {
        match (self.channels, self.samples) {
            (1, Samples::U16(data)) => Ok(ImageBuf {
                width: self.width,
                height: self.height,
                data,
            }),
            (channels, samples) => Err(Decoded {
                channels,
                samples,
                ..self
            }),
        }
    }
}

/// 8-bit gray or RGB samples as PNG bytes: fast compression, adaptive filters (`image`'s
/// defaults, so the files are byte for byte what it wrote).
pub(crate) fn encode_png8(
    samples: &[u8],
    width: usize,
    height: usize,
    color: png::ColorType,
) -> Result<Vec<u8>, png::EncodingError> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
    enc.set_color(color);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    enc.set_filter(png::Filter::Adaptive);
    enc.write_header()?.write_image_data(samples)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png16(width: u32, height: u32, color: png::ColorType, samples: &[u16]) -> Vec<u8> {
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(color);
        enc.set_depth(png::BitDepth::Sixteen);
        let be: Vec<u8> = samples.iter().flat_map(|v| v.to_be_bytes()).collect();
        enc.write_header().unwrap().write_image_data(&be).unwrap();
        out
    }

    #[test]
    fn sixteen_bit_and_alpha_convert_as_image_did() {
        let rgba = png16(
            2,
            1,
            png::ColorType::Rgba,
            &[65535, 257, 128, 0, 127, 0, 65535, 9],
        );
        let d = decode(&rgba).unwrap();
        assert_eq!(d.color_name(), "Rgba16");
        assert_eq!(d.to_rgb8().data, vec![[255, 1, 0], [0, 0, 255]]);
        let gray = decode(&png16(1, 1, png::ColorType::Grayscale, &[1000])).unwrap();
        assert_eq!(gray.clone().into_gray16().unwrap().data, vec![1000]);
        assert_eq!(gray.to_gray8().data, vec![luma([4, 4, 4])]);
        let la = encode_png8(&[9, 200], 1, 1, png::ColorType::GrayscaleAlpha).unwrap();
        let la = decode(&la).unwrap();
        assert_eq!(la.to_rgb8().data, vec![[9, 9, 9]]);
        assert!(la.into_gray16().is_err());
    }

    #[test]
    fn gray_jpeg_stays_gray_and_colour_is_rgb() {
        let mut gray = Vec::new();
        jpeg_encoder::Encoder::new(&mut gray, 90)
            .encode(&[128; 64], 8, 8, jpeg_encoder::ColorType::Luma)
            .unwrap();
        let d = decode(&gray).unwrap();
        assert_eq!((d.width, d.height, d.channels), (8, 8, 1));
        assert_eq!(dimensions(&gray).unwrap(), (8, 8));
        let rgb = crate::encode_jpeg(&Rgb8::new(16, 8, [200, 10, 10]), 95).unwrap();
        let d = decode(&rgb).unwrap();
        assert_eq!((d.width, d.height, d.channels), (16, 8, 3));
        assert!(d.to_rgb8().data.iter().all(|p| p[0] > 180 && p[1] < 40));
    }

    #[test]
    fn file_dimensions_reads_past_large_metadata() {
        let dir = tempfile::tempdir().unwrap();
        let png = dir.path().join("a.png");
        crate::write_rgb(&png, &Rgb8::new(7, 5, [1, 2, 3])).unwrap();
        assert_eq!(file_dimensions(&png).unwrap(), Some((7, 5)));
        // Two 60 KB APP15 segments before the frame header push it past the first read.
        let jpeg = crate::encode_jpeg(&Rgb8::new(9, 4, [9, 9, 9]), 90).unwrap();
        let mut big = jpeg[..2].to_vec();
        for _ in 0..2 {
            big.extend_from_slice(&[0xFF, 0xEF, 0xEA, 0x62]); // length 60002
            big.extend(std::iter::repeat_n(0u8, 60000));
        }
        big.extend_from_slice(&jpeg[2..]);
        let path = dir.path().join("b.jpg");
        std::fs::write(&path, &big).unwrap();
        assert_eq!(file_dimensions(&path).unwrap(), Some((9, 4)));
        std::fs::write(&path, b"neither").unwrap();
        assert_eq!(file_dimensions(&path).unwrap(), None);
    }

    #[test]
    fn a_jpeg_cut_short_is_told_from_a_whole_one() {
        let mut img = Rgb8::new(64, 64, [0, 0, 0]);
        for (i, p) in img.data.iter_mut().enumerate() {
            *p = [
                (i * 37 % 251) as u8,
                (i * 11 % 253) as u8,
                (i % 64 * 4) as u8,
            ];
        }
        let jpeg = crate::encode_jpeg(&img, 90).unwrap();
        assert!(!jpeg_truncated(&jpeg));
        // bytes after the end marker (a camera's padding) leave it whole
        let mut padded = jpeg.clone();
        padded.extend_from_slice(&[0; 16]);
        assert!(!jpeg_truncated(&padded));
        for cut_off in [2, 300] {
            let cut = &jpeg[..jpeg.len() - cut_off];
            assert!(jpeg_truncated(cut));
            assert_eq!(decode(cut).unwrap().width, 64, "still decoded, leniently");
        }
        let png = encode_png8(&[0; 12], 2, 2, png::ColorType::Rgb).unwrap();
        assert!(!jpeg_truncated(&png));
    }

    #[test]
    fn bad_bytes_and_huge_declared_sizes_are_errors() {
        assert!(matches!(decode(b"GIF89a"), Err(DecodeError::UnknownFormat)));
        let png = encode_png8(&[0; 12], 2, 2, png::ColorType::Rgb).unwrap();
        assert!(decode(&png[..png.len() / 2]).is_err());
        assert!(decode(&[0xFF, 0xD8, 0xFF, 0xE0, 0, 2]).is_err());
        assert!(matches!(
            check_size(40_000, 40_000, 3, 1),
            Err(DecodeError::TooLarge { .. })
        ));
        assert!(check_size(usize::MAX, 2, 1, 1).is_err());
    }
}
