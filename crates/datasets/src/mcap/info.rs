//! What a recording holds (`stillpoint info`): its topics, their types and counts, and the size
//! and encoding of each image topic's first message.

use super::file::{self, MessageSource};
use super::ros::{ImageMsg, MessageType};
use crate::error::DatasetError;
use serde::Serialize;
use std::path::Path;

/// A recording's contents.
#[derive(Clone, Debug, Serialize)]
pub struct RecordingInfo {
    /// The file read.
    pub file: String,
    /// Its size, bytes.
    pub bytes: u64,
    /// Chunk compressions (`zstd`, `lz4`; `none`), empty when nothing is chunked.
    pub compression: Vec<String>,
    /// Messages on all topics.
    pub messages: u64,
    /// From the first to the last stamp, seconds.
    pub duration_s: f64,
    /// Per topic, by name.
    pub topics: Vec<TopicInfo>,
}

/// One topic.
#[derive(Clone, Debug, Serialize)]
pub struct TopicInfo {
    /// Name.
    pub topic: String,
    /// Message type (schema name).
    #[serde(rename = "type")]
    pub ty: String,
    /// Message encoding (`cdr`, `ros1`, ...).
    pub encoding: String,
    /// Messages.
    pub messages: u64,
    /// First and last stamp (`header.stamp` for camera messages, else log time), seconds.
    pub first_stamp: Option<f64>,
    /// Last stamp, seconds.
    pub last_stamp: Option<f64>,
    /// Messages per second over the stamps' span.
    pub rate_hz: Option<f64>,
    /// Image topics: width of the first image.
    pub width: Option<u32>,
    /// Image topics: height of the first image.
    pub height: Option<u32>,
    /// Image topics: the first image's encoding (`rgb8`, `16UC1`) or compressed format.
    pub image_encoding: Option<String>,
    /// Why the first image could not be read, when it could not.
    pub error: Option<String>,
}

/// Read `path` once and describe it. A ROS 2 bag folder holding one `.mcap` is read as that file.
pub fn inspect(path: &Path) -> Result<RecordingInfo, DatasetError> {
    let path = super::recording_file(path)?;
    let scan = file::scan(&path, &|_| false)?;
    let mut topics: Vec<TopicInfo> = scan
        .channels
        .iter()
        .map(|(id, c)| {
            let stats = scan.stats.get(id).cloned().unwrap_or_default();
            let (first, last) = stats.stamps.unzip();
            let rate = stats
                .stamps
                .filter(|(a, b)| b > a && stats.count > 1)
                .map(|(a, b)| (stats.count - 1) as f64 / (b - a));
            let mut t = TopicInfo {
                topic: c.topic.clone(),
                ty: c.schema_name.clone(),
                encoding: c.message_encoding.clone(),
                messages: stats.count,
                first_stamp: first,
                last_stamp: last,
                rate_hz: rate,
                width: None,
                height: None,
                image_encoding: None,
                error: None,
            };
            if let (Some(ty), Some(wire), Some(m)) = (c.message_type(), c.wire(), stats.first)
                && ty.is_image()
            {
                match first_image(&path, *id, ty, wire, m.at) {
                    Ok((w, h, e)) => {
                        (t.width, t.height, t.image_encoding) = (Some(w), Some(h), Some(e));
                    }
                    Err(e) => t.error = Some(e.to_string()),
                }
            }
            t
        })
        .collect();
    topics.sort_by(|a, b| a.topic.cmp(&b.topic));
    let stamps = scan.stats.values().filter_map(|s| s.stamps);
    let first = stamps.clone().map(|s| s.0).reduce(f64::min);
    let last = stamps.map(|s| s.1).reduce(f64::max);
    Ok(RecordingInfo {
        file: path.display().to_string(),
        bytes: scan.bytes,
        compression: scan.compressions.clone(),
        messages: scan.stats.values().map(|s| s.count).sum(),
        duration_s: first.zip(last).map_or(0.0, |(a, b)| b - a),
        topics,
    })
}

/// Width, height and encoding of an image message.
fn first_image(
    path: &Path,
    channel: u16,
    ty: MessageType,
    wire: super::cdr::Wire,
    at: file::Location,
) -> Result<(u32, u32, String), String> {
    let bytes = MessageSource::new(path, vec![channel])
        .read(at)
        .map_err(|e| e.to_string())?;
    let msg = ImageMsg::decode(&bytes, wire, ty).map_err(|e| e.to_string())?;
    let (w, h) = msg.size()?;
    Ok((w, h, msg.encoding))
}

impl RecordingInfo {
    /// The table `stillpoint info` prints.
    pub fn table(&self) -> String {
        let mut out = format!(
            "{}: {} topics, {} messages, {:.1} s, {:.1} MB{}\n",
            self.file,
            self.topics.len(),
            self.messages,
            self.duration_s,
            self.bytes as f64 / 1e6,
            if self.compression.is_empty() {
                String::new()
            } else {
                format!(", chunks: {}", self.compression.join(", "))
            }
        );
        out += &format!(
            "{:<40} {:<34} {:<6} {:>9} {:>8}  first message\n",
            "topic", "type", "enc", "messages", "Hz"
        );
        for t in &self.topics {
            let first = match (&t.width, &t.height, &t.image_encoding, &t.error) {
                (Some(w), Some(h), Some(e), _) => format!("{w}x{h} {e}"),
                (_, _, _, Some(err)) => format!("unreadable: {err}"),
                _ => String::new(),
            };
            out += &format!(
                "{:<40} {:<34} {:<6} {:>9} {:>8}  {first}\n",
                t.topic,
                t.ty,
                t.encoding,
                t.messages,
                t.rate_hz.map_or("-".into(), |r| format!("{r:.1}")),
            );
        }
        out
    }
}
