//! The ROS camera messages (`sensor_msgs` Image, CompressedImage, CameraInfo) decoded, and
//! turned into the images a [`crate::Frame`] holds. Depth follows REP 118: `16UC1` in
//! millimetres, `32FC1` in metres.

use super::cdr::{DecodeError, MessageReader, Wire};
use stillpoint_geometry::{PinholeCamera, RadTan};
use stillpoint_image::{DepthMetres, ImageBuf, Rgb8, codec};

/// The message types read, whatever their package path (`sensor_msgs/msg/Image` in ROS 2,
/// `sensor_msgs/Image` in ROS 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MessageType {
    /// `sensor_msgs/Image`.
    Image,
    /// `sensor_msgs/CompressedImage`.
    CompressedImage,
    /// `sensor_msgs/CameraInfo`.
    CameraInfo,
}

impl MessageType {
    /// The type of a schema name, `None` for the others.
    pub fn from_schema_name(name: &str) -> Option<Self> {
        match name {
            "sensor_msgs/msg/Image" | "sensor_msgs/Image" => Some(Self::Image),
            "sensor_msgs/msg/CompressedImage" | "sensor_msgs/CompressedImage" => {
                Some(Self::CompressedImage)
            }
            "sensor_msgs/msg/CameraInfo" | "sensor_msgs/CameraInfo" => Some(Self::CameraInfo),
            _ => None,
        }
    }

    /// True for the two image types.
    pub fn is_image(self) -> bool {
        matches!(self, Self::Image | Self::CompressedImage)
    }
}

/// A `sensor_msgs/Image` or `sensor_msgs/CompressedImage`, its pixels borrowed from the message.
#[derive(Clone, Debug)]
pub struct ImageMsg<'a> {
    /// `header.stamp`, seconds.
    pub stamp: f64,
    /// Rows (0 for a compressed image: in the payload).
    pub height: u32,
    /// Columns (0 for a compressed image).
    pub width: u32,
    /// `rgb8`, `16UC1`, ...; for a compressed image its `format` (`jpeg`, `png`,
    /// `16UC1; compressedDepth png`, ...).
    pub encoding: String,
    /// Multi-byte pixels are big-endian.
    pub is_bigendian: bool,
    /// Bytes per row.
    pub step: u32,
    /// The pixels (compressed: the PNG / JPEG file).
    pub data: &'a [u8],
    /// True for a `CompressedImage`.
    pub compressed: bool,
}

impl<'a> ImageMsg<'a> {
    /// Decode a message of type `ty` (an image type).
    pub fn decode(bytes: &'a [u8], wire: Wire, ty: MessageType) -> Result<Self, DecodeError> {
        let mut r = MessageReader::new(bytes, wire)?;
        let (stamp, _frame) = r.header()?;
        if ty == MessageType::CompressedImage {
            let format = r.string("format")?;
            let data = r.bytes("data")?;
            return Ok(Self {
                stamp,
                height: 0,
                width: 0,
                encoding: format,
                is_bigendian: false,
                step: 0,
                data,
                compressed: true,
            });
        }
        let height = r.u32("height")?;
        let width = r.u32("width")?;
        let encoding = r.string("encoding")?;
        let is_bigendian = r.u8("is_bigendian")? != 0;
        let step = r.u32("step")?;
        let data = r.bytes("data")?;
        Ok(Self {
            stamp,
            height,
            width,
            encoding,
            is_bigendian,
            step,
            data,
            compressed: false,
        })
    }

    /// Width and height, reading a compressed image's file header when needed.
    pub fn size(&self) -> Result<(u32, u32), String> {
        if !self.compressed {
            return Ok((self.width, self.height));
        }
        let (_, payload) = self.compressed_payload()?;
        let (w, h) = codec::dimensions(payload).map_err(|e| format!("{}: {e}", self.encoding))?;
        Ok((w as u32, h as u32))
    }

    /// The pixels as 8-bit RGB (`rgb8`, `bgr8`, `rgba8`, `bgra8`, `mono8`; PNG / JPEG).
    pub fn to_rgb(&self) -> Result<Rgb8, String> {
        if self.compressed {
            let (_, payload) = self.compressed_payload()?;
            return codec::decode(payload)
                .map(|img| img.to_rgb8())
                .map_err(|e| format!("{}: {e}", self.encoding));
        }
        // Channel order, bytes per pixel.
        let (order, bpp): (PixelToRgb, usize) = match self.encoding.as_str() {
            "rgb8" => (|p| [p[0], p[1], p[2]], 3),
            "bgr8" => (|p| [p[2], p[1], p[0]], 3),
            "rgba8" => (|p| [p[0], p[1], p[2]], 4),
            "bgra8" => (|p| [p[2], p[1], p[0]], 4),
            "mono8" | "8UC1" => (|p| [p[0]; 3], 1),
            e => {
                return Err(format!(
                    "image encoding {e:?} is not supported for colour (rgb8, bgr8, rgba8, bgra8, mono8, or a jpeg/png CompressedImage)"
                ));
            }
        };
        let rows = self.rows(bpp)?;
        let data = rows
            .flat_map(|row| row.chunks_exact(bpp).map(order))
            .collect();
        ImageBuf::from_vec(self.width as usize, self.height as usize, data)
            .map_err(|e| e.to_string())
    }

    /// Depth in metres and the raw units per metre (`16UC1` / `mono16`: millimetres, 1000;
    /// `32FC1`: metres, 1). Non-finite and negative depths become 0, no measurement.
    pub fn to_depth(&self) -> Result<(DepthMetres, f64), String> {
        if self.compressed {
            return self.compressed_depth();
        }
        let big = self.is_bigendian;
        let (data, factor): (Vec<f32>, f64) = match self.encoding.as_str() {
            "16UC1" | "mono16" => {
                let rows = self.rows(2)?;
                let px = rows.flat_map(|r| r.chunks_exact(2)).map(|p| {
                    let b = [p[0], p[1]];
                    let v = if big {
                        u16::from_be_bytes(b)
                    } else {
                        u16::from_le_bytes(b)
                    };
                    // As `read_depth_metres` divides a PNG's values: the same f32.
                    v as f32 / 1000.0
                });
                (px.collect(), 1000.0)
            }
            "32FC1" => {
                let rows = self.rows(4)?;
                let px = rows.flat_map(|r| r.chunks_exact(4)).map(|p| {
                    let b = [p[0], p[1], p[2], p[3]];
                    let v = if big {
                        f32::from_be_bytes(b)
                    } else {
                        f32::from_le_bytes(b)
                    };
                    if v.is_finite() && v > 0.0 { v } else { 0.0 }
                });
                (px.collect(), 1.0)
            }
            e => {
                return Err(format!(
                    "image encoding {e:?} is not supported for depth (16UC1 or mono16 in millimetres, 32FC1 in metres)"
                ));
            }
        };
        let img = ImageBuf::from_vec(self.width as usize, self.height as usize, data)
            .map_err(|e| e.to_string())?;
        Ok((img, factor))
    }

    /// A compressed depth image: a 16-bit PNG in millimetres, bare or after the 12-byte header
    /// of `compressed_depth_image_transport` (`16UC1; compressedDepth png`).
    fn compressed_depth(&self) -> Result<(DepthMetres, f64), String> {
        let (kind, payload) = self.compressed_payload()?;
        if kind == CompressedKind::DepthFloat {
            return Err(format!(
                "{:?}: 32FC1 compressedDepth (quantised inverse depth) is not supported; record 16UC1 depth",
                self.encoding
            ));
        }
        let img = codec::decode(payload).map_err(|e| format!("{}: {e}", self.encoding))?;
        let g = img.into_gray16().map_err(|img| {
            format!(
                "{:?}: expected a 16-bit single-channel PNG for depth, found {}",
                self.encoding,
                img.color_name()
            )
        })?;
        let data = g.data.iter().map(|&v| v as f32 / 1000.0).collect();
        let img = ImageBuf::from_vec(g.width, g.height, data).map_err(|e| e.to_string())?;
        Ok((img, 1000.0))
    }

    /// What a compressed image holds, and its PNG / JPEG bytes.
    fn compressed_payload(&self) -> Result<(CompressedKind, &'a [u8]), String> {
        let f = self.encoding.to_ascii_lowercase();
        if !f.contains("compresseddepth") {
            return Ok((CompressedKind::Plain, self.data));
        }
        // compressed_depth_image_transport's ConfigHeader: format (i32) and two f32 depth
        // quantisation parameters, before the PNG.
        let payload = self
            .data
            .get(12..)
            .ok_or_else(|| format!("{f:?}: {} bytes, no room for its header", self.data.len()))?;
        let kind = if f.starts_with("32fc1") {
            CompressedKind::DepthFloat
        } else {
            CompressedKind::Plain
        };
        Ok((kind, payload))
    }

    /// The rows of a raw image, `bpp` bytes a pixel, each `width * bpp` long.
    fn rows(&self, bpp: usize) -> Result<impl Iterator<Item = &'a [u8]>, String> {
        let (w, h, step) = (
            self.width as usize,
            self.height as usize,
            self.step as usize,
        );
        let row = w * bpp;
        if step < row {
            return Err(format!(
                "step {step} is less than width {w} x {bpp} bytes ({})",
                self.encoding
            ));
        }
        let need = step * h.saturating_sub(1) + row;
        if h > 0 && self.data.len() < need {
            return Err(format!(
                "{}x{} {} needs {need} bytes, the message holds {}",
                w,
                h,
                self.encoding,
                self.data.len()
            ));
        }
        let data = self.data;
        Ok((0..h).map(move |y| &data[y * step..y * step + row]))
    }
}

/// One pixel's bytes as RGB.
type PixelToRgb = fn(&[u8]) -> [u8; 3];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum CompressedKind {
    Plain,
    DepthFloat,
}

/// A `sensor_msgs/CameraInfo`, the part a pinhole camera needs.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraInfoMsg {
    /// `header.stamp`, seconds.
    pub stamp: f64,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// `plumb_bob`, `rational_polynomial`, `equidistant`, ...
    pub distortion_model: String,
    /// The distortion coefficients (`D`).
    pub d: Vec<f64>,
    /// The intrinsic matrix (`K`), row-major.
    pub k: [f64; 9],
    /// The projection matrix of the rectified image (`P`), row-major 3x4.
    pub p: [f64; 12],
}

impl CameraInfoMsg {
    /// Decode one.
    pub fn decode(bytes: &[u8], wire: Wire) -> Result<Self, DecodeError> {
        let mut r = MessageReader::new(bytes, wire)?;
        let (stamp, _frame) = r.header()?;
        let height = r.u32("height")?;
        let width = r.u32("width")?;
        let distortion_model = r.string("distortion_model")?;
        let d = r.f64_seq("d")?;
        let k = r.f64_array::<9>("k")?;
        let _rotation = r.f64_array::<9>("r")?;
        let p = r.f64_array::<12>("p")?;
        Ok(Self {
            stamp,
            height,
            width,
            distortion_model,
            d,
            k,
            p,
        })
    }

    /// The camera: `K` and plumb-bob distortion, or for an already rectified image
    /// (`rectified`: the topic is an `image_rect*`) `P` and no distortion, as ROS's
    /// image_geometry reads them.
    pub fn camera(&self, rectified: bool) -> Result<PinholeCamera, String> {
        let (fx, fy, cx, cy) = if rectified {
            (self.p[0], self.p[5], self.p[2], self.p[6])
        } else {
            (self.k[0], self.k[4], self.k[2], self.k[5])
        };
        if !(fx > 0.0 && fy > 0.0 && self.width > 0 && self.height > 0) {
            return Err(format!(
                "the camera is not calibrated (fx {fx}, fy {fy}, {}x{})",
                self.width, self.height
            ));
        }
        let mut camera = PinholeCamera::new(fx, fy, cx, cy, self.width, self.height);
        if !rectified {
            camera.distortion = self.distortion()?;
        }
        Ok(camera)
    }

    /// `D` as radial-tangential coefficients.
    fn distortion(&self) -> Result<RadTan, String> {
        let d = &self.d;
        if d.iter().all(|&v| v == 0.0) {
            return Ok(RadTan::default());
        }
        let model = self.distortion_model.as_str();
        let plumb_bob = matches!(model, "plumb_bob" | "rational_polynomial");
        // rational_polynomial's k4..k6 are a denominator RadTan has not; zero, it is plumb_bob.
        let extra = d.get(5..).unwrap_or(&[]).iter().any(|&v| v != 0.0);
        if !plumb_bob || d.len() < 4 || extra {
            return Err(format!(
                "distortion model {model:?} with {} coefficients {d:?} is not supported (plumb_bob, 4 or 5 coefficients)",
                d.len()
            ));
        }
        Ok(RadTan {
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
            k3: d.get(4).copied().unwrap_or(0.0),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::cdr::CdrWriter;
    use super::*;

    fn image(encoding: &str, w: u32, h: u32, step: u32, data: &[u8]) -> Vec<u8> {
        let mut m = CdrWriter::new();
        m.header(10.0, "cam").u32(h).u32(w).string(encoding);
        m.u8(0).u32(step).bytes(data);
        m.finish()
    }

    #[test]
    fn raw_encodings_decode_with_row_padding() {
        // 2x2 bgr8 with one byte of padding a row.
        let px = [1, 2, 3, 4, 5, 6, 0, 7, 8, 9, 10, 11, 12, 0];
        let m = image("bgr8", 2, 2, 7, &px);
        let msg = ImageMsg::decode(&m, Wire::Cdr, MessageType::Image).unwrap();
        assert_eq!(msg.stamp, 10.0);
        let rgb = msg.to_rgb().unwrap();
        assert_eq!(
            rgb.data,
            vec![[3, 2, 1], [6, 5, 4], [9, 8, 7], [12, 11, 10]]
        );
        let m = image("mono8", 2, 1, 2, &[5, 6]);
        let msg = ImageMsg::decode(&m, Wire::Cdr, MessageType::Image).unwrap();
        assert_eq!(msg.to_rgb().unwrap().data, vec![[5; 3], [6; 3]]);
        // 16UC1 millimetres and 32FC1 metres (NaN = no measurement).
        let mm: Vec<u8> = [1500u16, 0].iter().flat_map(|v| v.to_le_bytes()).collect();
        let m = image("16UC1", 2, 1, 4, &mm);
        let msg = ImageMsg::decode(&m, Wire::Cdr, MessageType::Image).unwrap();
        let (d, f) = msg.to_depth().unwrap();
        assert_eq!((d.data.clone(), f), (vec![1.5, 0.0], 1000.0));
        let m: Vec<u8> = [2.25f32, f32::NAN]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let m = image("32FC1", 2, 1, 8, &m);
        let msg = ImageMsg::decode(&m, Wire::Cdr, MessageType::Image).unwrap();
        let (d, f) = msg.to_depth().unwrap();
        assert_eq!((d.data.clone(), f), (vec![2.25, 0.0], 1.0));
    }

    #[test]
    fn unsupported_and_short_images_are_errors() {
        let m = image("yuv422", 2, 1, 4, &[0; 4]);
        let msg = ImageMsg::decode(&m, Wire::Cdr, MessageType::Image).unwrap();
        let e = msg.to_rgb().unwrap_err();
        assert!(e.contains("\"yuv422\" is not supported"), "{e}");
        let e = msg.to_depth().unwrap_err();
        assert!(e.contains("16UC1"), "{e}");
        let m = image("rgb8", 4, 4, 12, &[0; 20]);
        let msg = ImageMsg::decode(&m, Wire::Cdr, MessageType::Image).unwrap();
        let e = msg.to_rgb().unwrap_err();
        assert!(e.contains("needs 48 bytes, the message holds 20"), "{e}");
    }

    #[test]
    fn compressed_images_decode_png() {
        let img = ImageBuf::from_vec(3, 2, (0..6).map(|i| [i % 3, i / 3, 7]).collect()).unwrap();
        let png = stillpoint_image::encode_png(&img).unwrap();
        let mut m = CdrWriter::new();
        m.header(1.0, "").string("png").bytes(&png);
        let m = m.finish();
        let msg = ImageMsg::decode(&m, Wire::Cdr, MessageType::CompressedImage).unwrap();
        assert_eq!(msg.size().unwrap(), (3, 2));
        let rgb = msg.to_rgb().unwrap();
        assert_eq!(rgb.get(2, 1), [2, 1, 7]);
    }

    #[test]
    fn camera_info_gives_k_and_plumb_bob() {
        let mut m = CdrWriter::new();
        m.header(0.0, "cam").u32(480).u32(640).string("plumb_bob");
        m.f64_seq(&[0.1, -0.2, 0.001, 0.002, 0.3]);
        let k = [500.0, 0.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0];
        let p = [
            400.0, 0.0, 300.0, 0.0, 0.0, 410.0, 200.0, 0.0, 0.0, 0.0, 1.0, 0.0,
        ];
        k.iter().chain(&[0.0; 9]).chain(&p).for_each(|&v| {
            m.f64(v);
        });
        m.u32(0).u32(0);
        let m = m.finish();
        let info = CameraInfoMsg::decode(&m, Wire::Cdr).unwrap();
        let c = info.camera(false).unwrap();
        assert_eq!((c.fx, c.fy, c.cx, c.cy), (500.0, 510.0, 320.0, 240.0));
        assert_eq!((c.width, c.height), (640, 480));
        assert_eq!((c.distortion.k1, c.distortion.k3), (0.1, 0.3));
        let r = info.camera(true).unwrap();
        assert_eq!((r.fx, r.fy, r.cx, r.cy), (400.0, 410.0, 300.0, 200.0));
        assert_eq!(r.distortion, RadTan::default());
    }
}
