"""An independent ROS 2 peer for `stillpoint ros2`: Eclipse Cyclone DDS (the DDS under
rmw_cyclonedds) publishes a sequence folder (the synth layout: rgb.txt, depth.txt,
settings.toml) as a RealSense driver's topics, and listens to the node's odometry and state.

Lock-step (`--lock-step`): reliable, each frame sent once the node's state for the previous
one came back. Live: best effort at the sequence's frame rate, whatever the node does.

    python tests/ros2/peer.py SEQ [--lock-step] [--frames N] [--rate HZ] [--json OUT]
"""

import argparse
import json
import os
import sys
import time
import tomllib

import numpy as np
from PIL import Image as PilImage
from cyclonedds.core import InstanceState, Policy, Qos, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import ros_messages as m  # noqa: E402

IMAGE = "/camera/camera/color/image_raw"
DEPTH = "/camera/camera/aligned_depth_to_color/image_raw"
INFO = "/camera/camera/color/camera_info"
FRAME = "camera_color_optical_frame"


def read_list(path):
    rows = []
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        t, f = line.split()[:2]
        rows.append((float(t), f))
    return rows


def read_settings(seq):
    with open(os.path.join(seq, "settings.toml"), "rb") as f:
        return tomllib.load(f)


def stereo_frames(seq, limit=None):
    """(stamp, left, right) gray uint8 per frame of a KITTI-layout pair (synth --stereo)."""
    times = [float(line) for line in open(os.path.join(seq, "times.txt")) if line.strip()]
    for i, t in enumerate(times[:limit]):
        name = f"{i:06d}.png"
        left = np.asarray(PilImage.open(os.path.join(seq, "image_0", name)).convert("L"))
        right = np.asarray(PilImage.open(os.path.join(seq, "image_1", name)).convert("L"))
        yield t, left, right


def frames(seq, limit=None):
    """(stamp, rgb uint8 HxWx3, depth float32 metres HxW) per frame."""
    rgb = read_list(os.path.join(seq, "rgb.txt"))
    depth = read_list(os.path.join(seq, "depth.txt"))
    factor = read_settings(seq).get("depth_factor", 5000.0)
    for (t, f), (_, d) in list(zip(rgb, depth))[:limit]:
        img = np.asarray(PilImage.open(os.path.join(seq, f)).convert("RGB"))
        raw = np.asarray(PilImage.open(os.path.join(seq, d)), dtype=np.uint16)
        # As stillpoint reads a PNG: the 16-bit value over the depth factor, in float32.
        yield t, img, raw.astype(np.float32) / np.float32(factor)


class Peer:
    """The camera's publishers and the node's subscriptions on one Cyclone participant."""

    def __init__(self, seq, reliable, image_topic=IMAGE, second_topic=DEPTH, settings="settings.toml"):
        with open(os.path.join(seq, settings), "rb") as f:
            s = tomllib.load(f)
        self.camera = s["camera"]
        self.fps = s.get("fps", 30.0)
        self.dp = DomainParticipant(int(os.environ.get("ROS_DOMAIN_ID", "0")))
        if reliable:
            qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepAll)
        else:
            qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(2))
        latched = Qos(
            Policy.Reliability.Reliable(duration(seconds=1)),
            Policy.Durability.TransientLocal,
            Policy.History.KeepLast(1),
        )
        answers = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepAll)
        dp = self.dp
        self.w_img = DataWriter(dp, Topic(dp, "rt" + image_topic, m.Image), qos)
        self.w_depth = DataWriter(dp, Topic(dp, "rt" + second_topic, m.Image), qos) if second_topic else None
        info_topic = image_topic.rsplit("/", 1)[0] + "/camera_info"
        self.w_info = DataWriter(dp, Topic(dp, "rt" + info_topic, m.CameraInfo), latched)
        self.r_state = DataReader(dp, Topic(dp, "rt/stillpoint/state", m.String), answers)
        self.r_odom = DataReader(dp, Topic(dp, "rt/stillpoint/odom", m.Odometry), answers)
        self.r_tf = DataReader(dp, Topic(dp, "rt/tf", m.TFMessage), answers)
        self.w_tf_static = DataWriter(
            dp,
            Topic(dp, "rt/tf_static", m.TFMessage),
            Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.TransientLocal,
                Policy.History.KeepLast(100)),
        )
        self.tf = []
        self.r_annotated = DataReader(
            dp, Topic(dp, "rt/stillpoint/image_annotated/compressed", m.CompressedImage), answers
        )
        self.waitset = WaitSet(dp)
        self.waitset.attach(
            ReadCondition(self.r_state, ViewState.Any | InstanceState.Any | SampleState.NotRead)
        )
        c = self.camera
        fx, fy, cx, cy = c["fx"], c["fy"], c["cx"], c["cy"]
        self.w_info.write(
            m.CameraInfo(
                header=m.Header(frame_id=FRAME),
                height=c["height"],
                width=c["width"],
                distortion_model="plumb_bob",
                d=[0.0] * 5,
                k=[fx, 0, cx, 0, fy, cy, 0, 0, 1],
                r=[1.0, 0, 0, 0, 1, 0, 0, 0, 1],
                p=[fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0],
            )
        )
        self.states, self.odometry = [], []

    def wait_for_node(self, timeout, lock_step):
        """Until the node subscribes to the images (and, lock-step, publishes its state)."""
        deadline = time.monotonic() + timeout

        def matched():
            ok = self.w_img.get_matched_subscriptions() and (
                self.w_depth is None or self.w_depth.get_matched_subscriptions()
            )
            return ok and (not lock_step or self.r_state.get_matched_publications())

        while not matched():
            if time.monotonic() > deadline:
                raise TimeoutError("the node did not appear on the topics")
            time.sleep(0.05)

    @staticmethod
    def image(t, a, frame_id):
        """A sensor_msgs/Image of an array: rgb8 (HxWx3 uint8), mono8 (HxW uint8) or 32FC1."""
        h, w = a.shape[:2]
        enc, step = {
            (np.dtype(np.uint8), 3): ("rgb8", w * 3),
            (np.dtype(np.uint8), 2): ("mono8", w),
            (np.dtype(np.float32), 2): ("32FC1", w * 4),
        }[(a.dtype, a.ndim)]
        header = m.Header(stamp=m.stamp(t), frame_id=frame_id)
        return m.Image(header=header, height=h, width=w, encoding=enc, step=step, data=a.tobytes())

    def send_depth(self, t, second, frame_id=FRAME):
        self.w_depth.write(self.image(t, second, frame_id))

    def send(self, t, img, second, frame_id=FRAME):
        """The frame's second image (depth or right) first, then its image."""
        if second is not None:
            self.send_depth(t, second, frame_id)
        self.w_img.write(self.image(t, img, frame_id))

    def send_raw_image(self, msg):
        self.w_img.write(msg)

    def wait_state(self, timeout):
        """The node's next state words (at least one), or TimeoutError."""
        got = []
        while not got:
            if self.waitset.wait(duration(seconds=timeout)) == 0:
                raise TimeoutError(f"no state from the node within {timeout} s")
            got = self.r_state.take(N=100)
        self.states += [s.data for s in got]
        self.odometry += self.r_odom.take(N=1000)
        self.tf += [t for msg in self.r_tf.take(N=1000) for t in msg.transforms]
        return got

    def collect(self):
        self.states += [s.data for s in self.r_state.take(N=1000)]
        self.odometry += self.r_odom.take(N=1000)
        self.tf += [t for msg in self.r_tf.take(N=1000) for t in msg.transforms]


def run(seq, lock_step, limit=None, rate=None, timeout=60.0):
    peer = Peer(seq, reliable=lock_step)
    peer.wait_for_node(timeout, lock_step)
    # Decoded before the clock starts (a camera driver does not decode PNGs, and the peer
    # shares the node's cores).
    todo = frames(seq, limit) if lock_step else list(frames(seq, limit))
    period = 1.0 / (rate or peer.fps)
    sent = 0
    start = time.monotonic()
    for k, (t, img, metres) in enumerate(todo):
        if not lock_step:
            wait = start + k * period - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        peer.send(t, img, metres)
        sent += 1
        if lock_step:
            peer.wait_state(timeout)
        else:
            peer.collect()
    if not lock_step:
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            peer.collect()
            time.sleep(0.05)
    return {
        "annotated": peer.r_annotated.take(N=10000),
        "sent": sent,
        "states": peer.states,
        "odometry": [
            [o.header.stamp.sec, o.header.stamp.nanosec, o.pose.pose.position.x, o.pose.pose.position.y,
             o.pose.pose.position.z, o.pose.pose.orientation.x, o.pose.pose.orientation.y,
             o.pose.pose.orientation.z, o.pose.pose.orientation.w, o.header.frame_id, o.child_frame_id]
            for o in peer.odometry
        ],
    }


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("seq")
    ap.add_argument("--lock-step", action="store_true")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--rate", type=float, default=None, help="Hz (default: the sequence's fps)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--timeout", type=float, default=60.0)
    a = ap.parse_args(argv)
    r = run(a.seq, a.lock_step, a.frames, a.rate, a.timeout)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(r, f)
    print(f"sent {r['sent']} frames, {len(r['states'])} states, {len(r['odometry'])} odometry messages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
