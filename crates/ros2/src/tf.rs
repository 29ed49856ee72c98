//! What the robot says about its frames: `/tf` and `/tf_static` read into the latest transform
//! of each frame to its parent, enough to close `odom` -> ... -> camera (REP 105) and to see
//! whether another node already parents the camera's frame.

use std::collections::HashMap;

use rustdds::no_key::SimpleDataReader;
use rustdds::{DomainParticipant, Subscriber, TopicKind};
use stillpoint_geometry::Se3;
use tracing::warn;

use crate::msg::{TF_MESSAGE, decode_tf};
use crate::wire::{CdrMessage, RawCdr};
use crate::{Ros2Error, dds_topic_name, qos};

/// The latest transform of each frame to its parent.
#[derive(Default)]
pub struct TfTree {
    parents: HashMap<String, (String, Se3)>,
}

impl TfTree {
    /// Record `child` in `parent`.
    pub fn set(&mut self, parent: String, child: String, child_to_parent: Se3) {
        self.parents.insert(child, (parent, child_to_parent));
    }

    /// The parent of `frame`, when one is known.
    pub fn parent(&self, frame: &str) -> Option<&str> {
        self.parents.get(frame).map(|(p, _)| p.as_str())
    }

    /// `frame` in `ancestor` (frame to ancestor), walking up the parents.
    pub fn lookup(&self, ancestor: &str, frame: &str) -> Option<Se3> {
        let mut t = Se3::identity();
        let mut at = frame;
        for _ in 0..64 {
            if at == ancestor {
                return Some(t);
            }
            let (parent, to_parent) = self.parents.get(at)?;
            t = to_parent * t;
            at = parent;
        }
        None
    }
}

/// The `/tf` and `/tf_static` subscriptions and the tree they fill.
pub(crate) struct TfListener {
    readers: Vec<SimpleDataReader<CdrMessage, RawCdr>>,
    pub(crate) tree: TfTree,
    /// Transforms this node publishes (parent, child): not the robot's.
    own: Vec<(String, String)>,
    bad: usize,
}

impl TfListener {
    pub(crate) fn new(
        participant: &DomainParticipant,
        subscriber: &Subscriber,
    ) -> Result<Self, Ros2Error> {
        let dynamic = qos(true, 100, false);
        let latched = qos(true, 100, true);
        let mut readers = Vec::new();
        for (topic, qos) in [("/tf", &dynamic), ("/tf_static", &latched)] {
            let t = participant
                .create_topic(
                    dds_topic_name(topic)?,
                    TF_MESSAGE.dds_name(),
                    qos,
                    TopicKind::NoKey,
                )
                .map_err(|e| Ros2Error::Dds(format!("topic {topic}: {e}")))?;
            readers.push(
                subscriber
                    .create_simple_datareader_no_key::<CdrMessage, RawCdr>(&t, Some(qos.clone()))
                    .map_err(|e| Ros2Error::Dds(format!("subscribing to {topic}: {e}")))?,
            );
        }
        Ok(Self {
            readers,
            tree: TfTree::default(),
            own: Vec::new(),
            bad: 0,
        })
    }

    /// A transform this node publishes, to be left out of the robot's tree.
    pub(crate) fn own(&mut self, parent: &str, child: &str) {
        let edge = (parent.to_string(), child.to_string());
        if !self.own.contains(&edge) {
            self.own.push(edge);
        }
    }

    /// Read what arrived.
    pub(crate) fn update(&mut self) {
        for reader in &self.readers {
            loop {
                let sample = match reader.try_take_one() {
                    Ok(Some(s)) => s.sample,
                    Ok(None) => break,
                    Err(_) => {
                        self.bad += 1;
                        continue;
                    }
                };
                match decode_tf(&sample.0) {
                    Ok(ts) => {
                        for (parent, child, t) in ts {
                            if !self.own.iter().any(|(p, c)| *p == parent && *c == child) {
                                self.tree.set(parent, child, t);
                            }
                        }
                    }
                    Err(e) => {
                        self.bad += 1;
                        if self.bad == 1 {
                            warn!("/tf: a sample skipped: {e} (later ones are counted)");
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stillpoint_geometry::Vec3;

    #[test]
    fn a_chain_of_frames_is_walked_up_to_its_ancestor() {
        let mut tree = TfTree::default();
        let base = Se3::new(Vec3::new(1.0, 2.0, 0.0), Vec3::new(0.0, 0.0, 0.5));
        let mount = Se3::new(Vec3::new(0.2, 0.0, 0.3), Vec3::new(0.0, 0.1, 0.0));
        let optical = Se3::new(Vec3::zeros(), Vec3::new(-1.2, 0.0, -1.2));
        tree.set("odom".into(), "base_link".into(), base);
        tree.set("base_link".into(), "camera_link".into(), mount);
        tree.set("camera_link".into(), "camera_optical".into(), optical);
        let t = tree.lookup("odom", "camera_optical").expect("a chain");
        let want = base * mount * optical;
        assert!((t.to_homogeneous() - want.to_homogeneous()).norm() < 1e-12);
        assert_eq!(tree.lookup("map", "camera_optical"), None);
        assert_eq!(
            tree.lookup("camera_optical", "camera_optical"),
            Some(Se3::identity())
        );
        assert_eq!(tree.parent("camera_link"), Some("base_link"));
    }
}
