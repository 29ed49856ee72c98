"""stillpoint: visual SLAM that stays accurate when the world moves.

>>> import stillpoint, numpy as np
>>> cam = stillpoint.Camera(535.4, 539.2, 320.1, 247.6, 640, 480)
>>> slam = stillpoint.Slam(cam, "rgbd", depth_scale=5000, detector="yolox")
>>> frame = slam.track(rgb, 0.0, depth=depth)   # rgb (480, 640, 3) uint8, depth (480, 640) uint16
>>> frame.pose, frame.state, frame.keypoints[frame.dynamic]
>>> run = slam.finish(); run.save_trajectory("traj.txt"); run.save_map("room.map")

`stillpoint.open(path)` reads a dataset folder, a video or a ROS recording as numpy frames;
`stillpoint.synth(preset, out)` writes a synthetic sequence with exact ground truth;
`stillpoint.eval.ate` / `rpe` give evo's numbers; `python -m stillpoint.batch` runs many
sequences x settings on Ray or a local process pool.

A Slam is used from one thread at a time (it may move between threads). `track` releases the
GIL while it works, so other Python threads (a camera reader, a viewer) run beside it.
"""

from ._stillpoint import (
    Camera,
    Error,
    Frame,
    Run,
    Slam,
    Source,
    SourceFrame,
    __version__,
    open,
    synth,
)
from . import eval  # noqa: E402  (after the extension: it re-exports from it)

__all__ = [
    "Camera",
    "Error",
    "Frame",
    "Run",
    "Slam",
    "Source",
    "SourceFrame",
    "__version__",
    "eval",
    "open",
    "synth",
]
