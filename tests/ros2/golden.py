"""Writes the golden CDR bytes of crates/ros2/tests/golden/ with Eclipse Cyclone DDS's own
serializer (the rmw_cyclonedds wire format), for the messages the node publishes and reads.
The Rust test builds the same messages with stillpoint's CDR writer and compares bytes.

    python tests/ros2/golden.py crates/ros2/tests/golden
"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import ros_messages as m  # noqa: E402

STAMP = m.Time(sec=1341846313, nanosec=533333000)


def pose(tx, ty, tz, qx, qy, qz, qw):
    return m.Pose(position=m.Point(tx, ty, tz), orientation=m.Quaternion(qx, qy, qz, qw))


def messages():
    p = pose(0.5, -1.25, 2.0, 0.0, 0.0, 0.6, 0.8)
    yield "odometry", m.Odometry(
        header=m.Header(stamp=STAMP, frame_id="map"),
        child_frame_id="camera_color_optical_frame",
        pose=m.PoseWithCovariance(pose=p),
    )
    yield "tf", m.TFMessage(
        transforms=[
            m.TransformStamped(
                header=m.Header(stamp=STAMP, frame_id="map"),
                child_frame_id="camera_color_optical_frame",
                transform=m.TransformMsg(m.Vector3(0.5, -1.25, 2.0), m.Quaternion(0.0, 0.0, 0.6, 0.8)),
            )
        ]
    )
    yield "path", m.Path(
        header=m.Header(stamp=STAMP, frame_id="map"),
        poses=[
            m.PoseStamped(header=m.Header(stamp=m.Time(1341846313, 500000000), frame_id="map"), pose=pose(0, 0, 0, 0, 0, 0, 1)),
            m.PoseStamped(header=m.Header(stamp=STAMP, frame_id="map"), pose=p),
        ],
    )
    points = [((1.0, 2.0, 3.0), (255, 128, 0)), ((-0.5, 0.25, 4.0), (1, 2, 3))]
    data = b"".join(
        b"".join(__import__("struct").pack("<f", v) for v in xyz)
        + __import__("struct").pack("<I", c[0] << 16 | c[1] << 8 | c[2])
        for xyz, c in points
    )
    yield "point_cloud", m.PointCloud2(
        header=m.Header(stamp=STAMP, frame_id="map"),
        height=1,
        width=2,
        fields=[m.PointField(n, 4 * i, 7, 1) for i, n in enumerate(["x", "y", "z", "rgb"])],
        is_bigendian=False,
        point_step=16,
        row_step=32,
        data=data,
        is_dense=True,
    )
    yield "compressed_image", m.CompressedImage(
        header=m.Header(stamp=STAMP, frame_id="camera"), format="jpeg", data=bytes([0xFF, 0xD8, 0xFF, 0xD9])
    )
    yield "string", m.String(data="tracking")
    # What the node reads: a 3x2 rgb8 image, a 3x2 32FC1 depth image, a CameraInfo.
    yield "image_rgb8", m.Image(
        header=m.Header(stamp=STAMP, frame_id="camera"), height=2, width=3, encoding="rgb8", step=9,
        data=bytes(range(18)),
    )
    yield "image_32fc1", m.Image(
        header=m.Header(stamp=STAMP, frame_id="camera"), height=2, width=3, encoding="32FC1", step=12,
        data=b"".join(__import__("struct").pack("<f", v) for v in [0.5, 1.0, 1.5, 0.0, 2.25, 3.0]),
    )
    yield "camera_info", m.CameraInfo(
        header=m.Header(stamp=STAMP, frame_id="camera"),
        height=480,
        width=640,
        distortion_model="plumb_bob",
        d=[0.1, -0.2, 0.001, 0.002, 0.0],
        k=[535.4, 0, 320.1, 0, 539.2, 247.6, 0, 0, 1],
        r=[1.0, 0, 0, 0, 1, 0, 0, 0, 1],
        p=[535.4, 0, 320.1, 0, 0, 539.2, 247.6, 0, 0, 0, 1, 0],
    )


def main():
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    for name, msg in messages():
        with open(os.path.join(out, name + ".cdr"), "wb") as f:
            f.write(msg.serialize())
        print(name, len(msg.serialize()))


if __name__ == "__main__":
    main()
