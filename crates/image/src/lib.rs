//! Plain image buffers shared by every stillpoint crate, and the PNG/JPEG IO they need.
//!
//! An image is a row-major `Vec` of pixels with its size; nothing more. Crates that call into
//! other libraries (the detector's engines) convert at their border.
//!
//! ```
//! use stillpoint_image::{Gray8, ImageBuf};
//! let mut img = Gray8::new(4, 3, 0);
//! img.set(1, 2, 200);
//! assert_eq!(img.get(1, 2), 200);
//! assert_eq!(img.data.len(), 12);
//! ```

#![deny(missing_docs)]

pub mod codec;
pub mod stereo_depth;

use std::path::{Path, PathBuf};

/// Errors from building or reading images.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file cannot be read or decoded.
    #[error("{path}: cannot read image: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The file cannot be encoded or written.
    #[error("{path}: cannot write image: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// An image cannot be encoded in memory.
    #[error("cannot encode a {width}x{height} image as {format}: {source}")]
    Encode {
        /// `png` or `jpeg`.
        format: &'static str,
        /// The image's size.
        width: usize,
        /// The image's size.
        height: usize,
        /// Why.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A depth image that is not 16-bit, one channel.
    #[error("{path}: expected a 16-bit single-channel depth PNG, found {found}")]
    NotDepth16 {
        /// The file.
        path: PathBuf,
        /// What it holds instead.
        found: String,
    },
    /// Pixels and size disagree.
    #[error("image buffer of {len} pixels does not match size {width}x{height}")]
    SizeMismatch {
        /// The size asked for.
        width: usize,
        /// The size asked for.
        height: usize,
        /// The pixels given.
        len: usize,
    },
}

/// A row-major image of `T` pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageBuf<T> {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width * height` pixels, row after row.
    pub data: Vec<T>,
}

/// 8-bit grayscale.
pub type Gray8 = ImageBuf<u8>;
/// 8-bit RGB.
pub type Rgb8 = ImageBuf<[u8; 3]>;
/// Depth in metres; 0 (or non-finite) means no measurement.
pub type DepthMetres = ImageBuf<f32>;

impl<T: Clone> ImageBuf<T> {
    /// An image filled with `value`.
    pub fn new(width: usize, height: usize, value: T) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// Wrap a buffer, checking its length.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Result<Self, ImageError> {
        if data.len() != width * height {
            return Err(ImageError::SizeMismatch {
                width,
                height,
                len: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }
}

impl<T: Copy> ImageBuf<T> {
    /// Pixel at column `x`, row `y`. Panics when out of bounds, like slice indexing.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> T {
        self.data[y * self.width + x]
    }

    /// Set the pixel at column `x`, row `y`.
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: T) {
        self.data[y * self.width + x] = v;
    }

    /// Pixel at (x, y) if inside the image.
    #[inline]
    pub fn get_checked(&self, x: isize, y: isize) -> Option<T> {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            None
        } else {
            Some(self.get(x as usize, y as usize))
        }
    }

    /// One row as a slice.
    #[inline]
    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// True when the image holds no pixel.
    pub fn is_empty(&self) -> bool {
        self.width == 0 || self.height == 0
    }
}

/// ITU-R 601 luma, as OpenCV's `cvtColor(RGB2GRAY)` computes it (fixed point, rounded).
#[inline]
pub fn luma(p: [u8; 3]) -> u8 {
    ((p[0] as u32 * 4899 + p[1] as u32 * 9617 + p[2] as u32 * 1868 + (1 << 13)) >> 14) as u8
}

/// Convert RGB to grayscale.
pub fn rgb_to_gray(rgb: &Rgb8) -> Gray8 {
    ImageBuf {
        width: rgb.width,
        height: rgb.height,
        data: rgb.data.iter().map(|&p| luma(p)).collect(),
    }
}

/// Replicate a grayscale image into the three channels (for a colour-only consumer such as the
/// detector on KITTI's or EuRoC's gray cameras).
pub fn gray_to_rgb(gray: &Gray8) -> Rgb8 {
    ImageBuf {
        width: gray.width,
        height: gray.height,
        data: gray.data.iter().map(|&v| [v; 3]).collect(),
    }
}

/// Resample `img` through `map` (OpenCV's `remap` with bilinear interpolation): output pixel
/// i of a `width` x `height` image (row-major) takes `img` at the sub-pixel position `map[i]`;
/// positions outside `img` give 0. `None` when `map` does not hold `width * height` entries.
///
/// ```
/// use stillpoint_image::{Gray8, remap_bilinear};
/// let img = Gray8::from_vec(2, 1, vec![0, 100]).unwrap();
/// let out = remap_bilinear(&img, &[[0.5, 0.0], [1.0, 0.0], [5.0, 0.0]], 3, 1).unwrap();
/// assert_eq!(out.data, vec![50, 100, 0]);
/// ```
pub fn remap_bilinear(img: &Gray8, map: &[[f32; 2]], width: usize, height: usize) -> Option<Gray8> {
    if map.len() != width * height {
        return None;
    }
    let (w, h) = (img.width as f32, img.height as f32);
    let data = map
        .iter()
        .map(|&[x, y]| {
            // NaN fails these comparisons too.
            if !(x >= 0.0 && y >= 0.0 && x <= w - 1.0 && y <= h - 1.0) {
                return 0;
            }
            let (x0, y0) = (x as usize, y as usize);
            let (x1, y1) = ((x0 + 1).min(img.width - 1), (y0 + 1).min(img.height - 1));
            let (ax, ay) = (x - x0 as f32, y - y0 as f32);
            let p = |xx: usize, yy: usize| img.data[yy * img.width + xx] as f32;
            let top = p(x0, y0) + ax * (p(x1, y0) - p(x0, y0));
            let bottom = p(x0, y1) + ax * (p(x1, y1) - p(x0, y1));
            (top + ay * (bottom - top)).round() as u8
        })
        .collect();
    Some(ImageBuf {
        width,
        height,
        data,
    })
}

fn read_err(path: &Path, e: impl std::error::Error + Send + Sync + 'static) -> ImageError {
    ImageError::Read {
        path: path.to_path_buf(),
        source: Box::new(e),
    }
}

fn write_err(path: &Path, e: impl std::error::Error + Send + Sync + 'static) -> ImageError {
    ImageError::Write {
        path: path.to_path_buf(),
        source: Box::new(e),
    }
}

fn decode_file(path: &Path) -> Result<codec::Decoded, ImageError> {
    let bytes = std::fs::read(path).map_err(|e| read_err(path, e))?;
    let decoded = codec::decode(&bytes).map_err(|e| read_err(path, e))?;
    if codec::jpeg_truncated(&bytes) {
        tracing::warn!(
            "{}: JPEG cut short (no end-of-image marker): decoded as far as it goes",
            path.display()
        );
    }
    Ok(decoded)
}

/// Read any PNG/JPEG as 8-bit RGB (16-bit input is scaled down, gray is replicated).
pub fn read_rgb(path: &Path) -> Result<Rgb8, ImageError> {
    Ok(decode_file(path)?.to_rgb8())
}

/// Read any PNG/JPEG as 8-bit grayscale (colour is converted with [`luma`]).
pub fn read_gray(path: &Path) -> Result<Gray8, ImageError> {
    Ok(decode_file(path)?.to_gray8())
}

/// Read a 16-bit single-channel depth PNG as raw values.
pub fn read_depth16(path: &Path) -> Result<ImageBuf<u16>, ImageError> {
    decode_file(path)?
        .into_gray16()
        .map_err(|other| ImageError::NotDepth16 {
            path: path.to_path_buf(),
            found: other.color_name().to_string(),
        })
}

/// Read a 16-bit depth PNG and divide by `factor` (TUM: 5000 units per metre). Zero stays zero.
pub fn read_depth_metres(path: &Path, factor: f32) -> Result<DepthMetres, ImageError> {
    let raw = read_depth16(path)?;
    Ok(ImageBuf {
        width: raw.width,
        height: raw.height,
        data: raw.data.iter().map(|&d| d as f32 / factor).collect(),
    })
}

/// Write an 8-bit grayscale PNG.
pub fn write_gray(path: &Path, img: &Gray8) -> Result<(), ImageError> {
    let png = codec::encode_png8(&img.data, img.width, img.height, png::ColorType::Grayscale)
        .map_err(|e| write_err(path, e))?;
    std::fs::write(path, png).map_err(|e| write_err(path, e))
}

/// Write an 8-bit RGB PNG.
pub fn write_rgb(path: &Path, img: &Rgb8) -> Result<(), ImageError> {
    let png = encode_png(img).map_err(|e| write_err(path, e))?;
    std::fs::write(path, png).map_err(|e| write_err(path, e))
}

/// An 8-bit RGB image as the bytes of a PNG file (fast compression: for streams of frames).
pub fn encode_png(img: &Rgb8) -> Result<Vec<u8>, ImageError> {
    codec::encode_png8(&flat_rgb(img), img.width, img.height, png::ColorType::Rgb)
        .map_err(|e| encode_err("png", img, e))
}

/// An 8-bit RGB image as the bytes of a JPEG file of `quality` (1..=100). The jpeg-encoder
/// crate (AVX2 where the CPU has it) takes half the time of image's own encoder: 8 against
/// 16 ms for 640x480.
pub fn encode_jpeg(img: &Rgb8, quality: u8) -> Result<Vec<u8>, ImageError> {
    let (Ok(w), Ok(h)) = (u16::try_from(img.width), u16::try_from(img.height)) else {
        return Err(encode_err(
            "jpeg",
            img,
            std::io::Error::other("larger than 65535 pixels a side"),
        ));
    };
    let mut out = Vec::new();
    jpeg_encoder::Encoder::new(&mut out, quality.clamp(1, 100))
        .encode(&flat_rgb(img), w, h, jpeg_encoder::ColorType::Rgb)
        .map_err(|e| encode_err("jpeg", img, e))?;
    Ok(out)
}

fn flat_rgb(img: &Rgb8) -> Vec<u8> {
    img.data.iter().flat_map(|p| p.iter().copied()).collect()
}

fn encode_err(
    format: &'static str,
    img: &Rgb8,
    e: impl std::error::Error + Send + Sync + 'static,
) -> ImageError {
    ImageError::Encode {
        format,
        width: img.width,
        height: img.height,
        source: Box::new(e),
    }
}

/// Write raw 16-bit values as a single-channel PNG (big-endian, as PNG requires).
pub fn write_depth16(path: &Path, img: &ImageBuf<u16>) -> Result<(), ImageError> {
    let file = std::fs::File::create(path).map_err(|e| write_err(path, e))?;
    let mut enc = png::Encoder::new(
        std::io::BufWriter::new(file),
        img.width as u32,
        img.height as u32,
    );
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    enc.set_compression(png::Compression::Fast);
    let mut w = enc.write_header().map_err(|e| write_err(path, e))?;
    let bytes: Vec<u8> = img.data.iter().flat_map(|v| v.to_be_bytes()).collect();
    w.write_image_data(&bytes).map_err(|e| write_err(path, e))
}

/// Write depth in metres as a 16-bit PNG with `factor` units per metre (non-finite or out of
/// range values become 0 = no measurement).
pub fn write_depth_metres(path: &Path, img: &DepthMetres, factor: f32) -> Result<(), ImageError> {
    let raw = ImageBuf {
        width: img.width,
        height: img.height,
        data: img
            .data
            .iter()
            .map(|&d| {
                let v = (d * factor).round();
                if v.is_finite() && v > 0.0 && v <= u16::MAX as f32 {
                    v as u16
                } else {
                    0
                }
            })
            .collect(),
    };
    write_depth16(path, &raw)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn remap_interpolates_and_leaves_outside_and_bad_positions_black() {
        // A horizontal ramp 0, 10, 20, ... sampled half a pixel right and a quarter down.
        let img = Gray8::from_vec(8, 4, (0..32).map(|i| (i % 8) as u8 * 10).collect()).unwrap();
        let map: Vec<[f32; 2]> = (0..8 * 4)
            .map(|i| [(i % 8) as f32 + 0.5, (i / 8) as f32 + 0.25])
            .collect();
        let out = remap_bilinear(&img, &map, 8, 4).unwrap();
        assert_eq!(&out.data[..8], &[5, 15, 25, 35, 45, 55, 65, 0]);
        // The last row's samples fall below the image.
        assert!(out.row(3).iter().all(|&v| v == 0));
        let odd = [[f32::NAN, 0.0], [-0.1, 0.0], [0.0, 3.0], [7.0, 0.0]];
        let out = remap_bilinear(&img, &odd, 4, 1).unwrap();
        assert_eq!(out.data, vec![0, 0, 0, 70]);
        assert!(remap_bilinear(&img, &odd, 5, 1).is_none());
        assert!(
            remap_bilinear(&Gray8::new(0, 0, 0), &[[0.0, 0.0]], 1, 1)
                .is_some_and(|o| o.data == [0])
        );
    }

    #[test]
    fn encoded_png_decodes_to_the_same_pixels_and_jpeg_to_a_jpeg() {
        let img = Rgb8::from_vec(5, 3, (0..15u8).map(|i| [i * 10, 255 - i, i]).collect()).unwrap();
        let png = encode_png(&img).unwrap();
        assert_eq!(codec::decode(&png).unwrap().to_rgb8(), img);
        let jpeg = encode_jpeg(&img, 90).unwrap();
        assert_eq!(codec::format_of(&jpeg), Some(codec::Format::Jpeg));
    }

    #[test]
    fn depth_roundtrip_is_exact_at_factor_resolution() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("d.png");
        let d = ImageBuf::from_vec(3, 1, vec![0.0, 1.2346, f32::NAN]).unwrap();
        write_depth_metres(&p, &d, 5000.0).unwrap();
        let back = read_depth_metres(&p, 5000.0).unwrap();
        assert_eq!(back.data[0], 0.0);
        assert!((back.data[1] - 1.2346).abs() < 1e-4);
        assert_eq!(back.data[2], 0.0);
    }

    #[test]
    fn gray_png_roundtrip_and_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.png");
        let g = ImageBuf::from_vec(2, 2, vec![0u8, 50, 100, 255]).unwrap();
        write_gray(&p, &g).unwrap();
        assert_eq!(read_gray(&p).unwrap(), g);
        // an 8-bit image is not a depth map
        let err = read_depth16(&p).unwrap_err().to_string();
        assert!(err.contains("16-bit"), "{err}");
        let missing = read_gray(&dir.path().join("nope.png"))
            .unwrap_err()
            .to_string();
        assert!(missing.contains("nope.png"), "{missing}");
        std::fs::write(&p, b"not a png").unwrap();
        assert!(read_rgb(&p).is_err());
    }

    #[test]
    fn size_mismatch_is_an_error() {
        assert!(ImageBuf::from_vec(2, 2, vec![0u8; 3]).is_err());
    }
}
