//! The camera as ROS 2 topics: the image (and depth, or right image) subscriptions, the first
//! `CameraInfo`, and frames paired by stamp handed to the run as a live source.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use rustdds::mio1::{Events, Interest, Poll, Token};
use rustdds::no_key::SimpleDataReader;
use rustdds::{QosPolicies, Subscriber, TopicKind};
use stillpoint_datasets::live::{CaptureSource, Captured};
use stillpoint_datasets::mcap::cdr::{MessageReader, Wire, stamp_seconds};
use stillpoint_datasets::mcap::ros::{CameraInfoMsg, ImageMsg, MessageType};
use stillpoint_datasets::{DatasetError, Sensor, Settings};
use stillpoint_image::rgb_to_gray;
use tracing::warn;

use crate::msg::{CAMERA_INFO, COMPRESSED_IMAGE, IMAGE, RosType, Stamp};
use crate::wire::{CdrMessage, RawCdr};
use crate::{Ros2Error, dds_topic_name};

type Reader = SimpleDataReader<CdrMessage, RawCdr>;

/// A frame handed to the run: its stamp (as the run has it, and exactly), the camera's frame
/// id, when its image was taken from DDS.
#[derive(Clone, Debug)]
pub struct Arrival {
    /// Seconds, the frame's timestamp.
    pub stamp: f64,
    /// The image header's stamp.
    pub exact: Stamp,
    /// The image header's frame id.
    pub frame_id: String,
    /// When the image was taken from DDS.
    pub at: Instant,
}

/// One subscription: its ROS name, its message type and its reader.
pub(crate) struct Subscription {
    pub(crate) topic: String,
    ty: MessageType,
    reader: Reader,
    /// Samples that could not be decoded, and whether that was said.
    bad: usize,
}

impl Subscription {
    /// Subscribe to `topic` (a `/compressed` suffix: `CompressedImage`).
    pub(crate) fn new(
        participant: &rustdds::DomainParticipant,
        subscriber: &Subscriber,
        topic: &str,
        ty: MessageType,
        qos: &QosPolicies,
    ) -> Result<Self, Ros2Error> {
        let ros_type: RosType = match ty {
            MessageType::Image => IMAGE,
            MessageType::CompressedImage => COMPRESSED_IMAGE,
            MessageType::CameraInfo => CAMERA_INFO,
        };
        let dds = participant
            .create_topic(
                dds_topic_name(topic)?,
                ros_type.dds_name(),
                qos,
                TopicKind::NoKey,
            )
            .map_err(|e| Ros2Error::Dds(format!("topic {topic}: {e}")))?;
        let reader = subscriber
            .create_simple_datareader_no_key::<CdrMessage, RawCdr>(&dds, Some(qos.clone()))
            .map_err(|e| Ros2Error::Dds(format!("subscribing to {topic}: {e}")))?;
        Ok(Self {
            topic: topic.to_string(),
            ty,
            reader,
            bad: 0,
        })
    }

    /// An image subscription: `CompressedImage` when the topic ends in `/compressed`.
    pub(crate) fn image(
        participant: &rustdds::DomainParticipant,
        subscriber: &Subscriber,
        topic: &str,
        qos: &QosPolicies,
    ) -> Result<Self, Ros2Error> {
        let ty = if topic.ends_with("/compressed") || topic.ends_with("/compressedDepth") {
            MessageType::CompressedImage
        } else {
            MessageType::Image
        };
        Self::new(participant, subscriber, topic, ty, qos)
    }

    /// The next sample's bytes, when one is there. A sample that is not CDR is logged once
    /// and skipped.
    fn take(&mut self) -> Option<CdrMessage> {
        loop {
            match self.reader.try_take_one() {
                Ok(Some(change)) => return Some(change.sample),
                Ok(None) => return None,
                Err(e) => self.bad(&format!("{e}")),
            }
        }
    }

    fn bad(&mut self, why: &str) {
        self.bad += 1;
        if self.bad == 1 {
            warn!(
                "{}: a sample skipped: {why} (later ones are counted)",
                self.topic
            );
        }
    }
}

/// Wait for the first `CameraInfo` on `info` that decodes. A log line every `warn_every`
/// while none comes; `None` when `stop` is set first.
pub(crate) fn wait_for_info(
    info: &mut Subscription,
    warn_every: Duration,
    stop: Option<&AtomicBool>,
) -> Result<Option<CameraInfoMsg>, Ros2Error> {
    let poll_err = |e: std::io::Error| Ros2Error::Dds(format!("poll: {e}"));
    let mut poll = Poll::new().map_err(poll_err)?;
    poll.registry()
        .register(&mut info.reader, Token(0), Interest::READABLE)
        .map_err(poll_err)?;
    let mut events = Events::with_capacity(4);
    let started = Instant::now();
    let mut warned = Duration::ZERO;
    loop {
        while let Some(m) = info.take() {
            match CameraInfoMsg::decode(&m.0, Wire::Cdr) {
                Ok(msg) => {
                    poll.registry()
                        .deregister(&mut info.reader)
                        .map_err(poll_err)?;
                    return Ok(Some(msg));
                }
                Err(e) => info.bad(&e.to_string()),
            }
        }
        if stop.is_some_and(|s| s.load(Ordering::SeqCst)) {
            return Ok(None);
        }
        if started.elapsed() >= warned + warn_every {
            warned += warn_every;
            warn!(
                "no CameraInfo on {} after {:.0} s; waiting (or give --settings FILE with the camera)",
                info.topic,
                warned.as_secs_f64()
            );
        }
        poll.poll(&mut events, Some(Duration::from_millis(100)))
            .map_err(poll_err)?;
    }
}

/// A received image: its stamp (as seconds, and exactly), its frame id, when it was taken from
/// DDS, the message.
struct Received {
    stamp: f64,
    exact: Stamp,
    frame_id: String,
    at: Instant,
    msg: CdrMessage,
}

/// The subscriptions of one camera, delivering frames whose images are paired by stamp.
pub(crate) struct RosCamera {
    pub(crate) image: Subscription,
    /// The depth or right image, paired with `image`.
    pub(crate) second: Option<(Subscription, Sensor)>,
    pub(crate) settings: Settings,
    pub(crate) tolerance: f64,
    pub(crate) silence: Duration,
    pub(crate) stop: Option<&'static AtomicBool>,
    /// Where each delivered frame's stamp and the camera frame go (for the outputs).
    pub(crate) frame_ids: std::sync::mpsc::Sender<Arrival>,
    images: VecDeque<Received>,
    seconds: VecDeque<Received>,
    poll: Option<Poll>,
    wrong_size: usize,
    last_frame: Instant,
    silent_said: bool,
}

/// Unpaired images kept per topic.
const KEEP: usize = 8;

impl RosCamera {
    pub(crate) fn new(
        image: Subscription,
        second: Option<(Subscription, Sensor)>,
        settings: Settings,
        tolerance: f64,
        silence: Duration,
        stop: Option<&'static AtomicBool>,
        frame_ids: std::sync::mpsc::Sender<Arrival>,
    ) -> Self {
        Self {
            image,
            second,
            settings,
            tolerance,
            silence,
            stop,
            frame_ids,
            images: VecDeque::new(),
            seconds: VecDeque::new(),
            poll: None,
            wrong_size: 0,
            last_frame: Instant::now(),
            silent_said: false,
        }
    }

    fn register(&mut self) -> Result<(), DatasetError> {
        if self.poll.is_some() {
            return Ok(());
        }
        let err = |e: std::io::Error| DatasetError::Ended {
            path: self.image.topic.clone(),
            at: "start".into(),
            msg: format!("poll: {e}"),
        };
        let poll = Poll::new().map_err(err)?;
        poll.registry()
            .register(&mut self.image.reader, Token(0), Interest::READABLE)
            .map_err(err)?;
        if let Some((s, _)) = self.second.as_mut() {
            poll.registry()
                .register(&mut s.reader, Token(1), Interest::READABLE)
                .map_err(err)?;
        }
        self.poll = Some(poll);
        Ok(())
    }

    /// Read what arrived into the queues; the stamps are read now, the pixels once paired.
    fn drain(&mut self) {
        while let Some(m) = self.image.take() {
            match header_of(&m) {
                Ok((exact, frame_id)) => push(&mut self.images, exact, frame_id, m),
                Err(e) => self.image.bad(&e),
            }
        }
        if let Some((s, _)) = self.second.as_mut() {
            while let Some(m) = s.take() {
                match header_of(&m) {
                    Ok((exact, frame_id)) => push(&mut self.seconds, exact, frame_id, m),
                    Err(e) => s.bad(&e),
                }
            }
        }
    }

    /// The closest pair of an image and its partner within the tolerance (the pair with the
    /// smallest stamp difference, so a stray image cannot take the partner of the next),
    /// older unpaired images dropped. A pair whose stamps differ is taken only once both
    /// topics have a newer message (a closer partner can no longer come), as ROS's
    /// approximate-time synchroniser waits; equal stamps (a RealSense's aligned depth) pair at
    /// once.
    fn pair(&mut self) -> Option<(Received, Option<Received>)> {
        if self.second.is_none() {
            return self.images.pop_front().map(|r| (r, None));
        }
        let mut best: Option<(usize, usize, f64)> = None;
        for (i, a) in self.images.iter().enumerate() {
            for (j, b) in self.seconds.iter().enumerate() {
                let d = (a.stamp - b.stamp).abs();
                if d <= self.tolerance && best.is_none_or(|(_, _, bd)| d < bd) {
                    best = Some((i, j, d));
                }
            }
        }
        let (i, j, d) = best?;
        if d > 0.0 && (i + 1 >= self.images.len() || j + 1 >= self.seconds.len()) {
            return None;
        }
        self.images.drain(..i);
        self.seconds.drain(..j);
        let image = self.images.pop_front()?;
        let second = self.seconds.pop_front();
        Some((image, second))
    }

    /// The pixels of a pair, checked against the camera's size.
    fn decode(&mut self, image: Received, second: Option<Received>) -> Option<Captured> {
        let size = (self.settings.camera.width, self.settings.camera.height);
        let rgb = ImageMsg::decode(&image.msg.0, Wire::Cdr, self.image.ty)
            .map_err(|e| e.to_string())
            .and_then(|m| m.to_rgb());
        let rgb = match rgb {
            Ok(rgb) => rgb,
            Err(e) => {
                self.image.bad(&e);
                return None;
            }
        };
        if (rgb.width as u32, rgb.height as u32) != size {
            self.wrong_size += 1;
            if self.wrong_size == 1 {
                warn!(
                    "{}: a {}x{} image, but the camera is {}x{}: skipped (later ones are counted)",
                    self.image.topic, rgb.width, rgb.height, size.0, size.1
                );
            }
            return None;
        }
        let mut captured = Captured {
            rgb,
            timestamp: image.stamp,
            depth: None,
            right: None,
        };
        if let (Some(r), Some((sub, sensor))) = (second, self.second.as_mut()) {
            let decoded = ImageMsg::decode(&r.msg.0, Wire::Cdr, sub.ty).map_err(|e| e.to_string());
            match sensor {
                Sensor::Rgbd => match decoded.and_then(|m| m.to_depth()) {
                    Ok((d, _)) if (d.width as u32, d.height as u32) == size => {
                        captured.depth = Some(d)
                    }
                    Ok(d) => {
                        sub.bad(&format!("a {}x{} depth image", d.0.width, d.0.height));
                        return None;
                    }
                    Err(e) => {
                        sub.bad(&e);
                        return None;
                    }
                },
                _ => match decoded.and_then(|m| m.to_rgb()) {
                    Ok(rgb) if (rgb.width as u32, rgb.height as u32) == size => {
                        captured.right = Some(rgb_to_gray(&rgb))
                    }
                    Ok(_) | Err(_) => {
                        sub.bad("a right image that does not decode to the camera's size");
                        return None;
                    }
                },
            }
        }
        let _ = self.frame_ids.send(Arrival {
            stamp: image.stamp,
            exact: image.exact,
            frame_id: image.frame_id,
            at: image.at,
        });
        Some(captured)
    }
}

/// Queue a received image, the oldest dropped beyond [`KEEP`].
fn push(q: &mut VecDeque<Received>, exact: Stamp, frame_id: String, msg: CdrMessage) {
    if q.len() >= KEEP {
        q.pop_front();
    }
    q.push_back(Received {
        stamp: stamp_seconds(i64::from(exact.sec), exact.nanosec),
        exact,
        frame_id,
        at: Instant::now(),
        msg,
    });
}

/// The stamp and frame id of an image message (every image type starts with its header).
fn header_of(m: &CdrMessage) -> Result<(Stamp, String), String> {
    let mut r = MessageReader::new(&m.0, Wire::Cdr).map_err(|e| e.to_string())?;
    let e = |e: stillpoint_datasets::mcap::cdr::DecodeError| e.to_string();
    let sec = r.i32("header.stamp.sec").map_err(e)?;
    let nanosec = r.u32("header.stamp.nanosec").map_err(e)?;
    if nanosec >= 1_000_000_000 {
        return Err(format!("header.stamp: {nanosec} nanoseconds"));
    }
    let frame_id = r.string("header.frame_id").map_err(e)?;
    Ok((Stamp { sec, nanosec }, frame_id))
}

impl CaptureSource for RosCamera {
    fn next_capture(&mut self) -> Result<Option<Captured>, DatasetError> {
        self.register()?;
        let mut events = Events::with_capacity(8);
        loop {
            self.drain();
            while let Some((image, second)) = self.pair() {
                if let Some(c) = self.decode(image, second) {
                    self.last_frame = Instant::now();
                    self.silent_said = false;
                    return Ok(Some(c));
                }
            }
            if self.stop.is_some_and(|s| s.load(Ordering::SeqCst)) {
                return Ok(None);
            }
            if !self.silent_said && self.last_frame.elapsed() >= self.silence {
                self.silent_said = true;
                warn!(
                    "no frame from {} for {:.0} s; waiting",
                    self.image.topic,
                    self.silence.as_secs_f64()
                );
            }
            if let Some(poll) = self.poll.as_mut() {
                poll.poll(&mut events, Some(Duration::from_millis(100)))
                    .map_err(|e| DatasetError::Ended {
                        path: self.image.topic.clone(),
                        at: "reading".into(),
                        msg: format!("poll: {e}"),
                    })?;
            }
        }
    }

    fn source_name(&self) -> String {
        self.image.topic.clone()
    }
}
