"""Type stubs of the compiled part of stillpoint (stillpoint._stillpoint)."""

from os import PathLike
from typing import Any, Iterator, Literal, Mapping, Sequence

import numpy as np
import numpy.typing as npt

__version__: str

StrPath = str | PathLike[str]
Sensor = Literal["rgbd", "stereo", "mono"]
BoxRows = Sequence[Sequence[float]] | npt.NDArray[np.float64]
TrajectoryLike = StrPath | npt.NDArray[np.float64]

class Error(RuntimeError):
    """A failure inside stillpoint: a file that cannot be read, settings that do not parse, a
    map made with another camera, a run that stopped."""

class Camera:
    """A pinhole camera with radial-tangential distortion (OpenCV's k1, k2, p1, p2, k3)."""
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    k1: float
    k2: float
    p1: float
    p2: float
    k3: float
    def __init__(
        self, fx: float, fy: float, cx: float, cy: float, width: int, height: int,
        k1: float = 0.0, k2: float = 0.0, p1: float = 0.0, p2: float = 0.0, k3: float = 0.0,
    ) -> None: ...

class Frame:
    """What happened to one frame."""
    index: int
    timestamp: float
    pose: npt.NDArray[np.float64] | None
    """Camera-to-world, (4, 4); None when the frame was not tracked."""
    state: Literal["ok", "lost", "not_initialized"]
    keypoints: npt.NDArray[np.float32]
    """(N, 2) pixels of every ORB keypoint, culled ones included."""
    dynamic: npt.NDArray[np.bool_]
    """(N,) True: judged on a moving object and removed before tracking."""
    matched: npt.NDArray[np.bool_]
    """(N,) True: matched to a map point and kept by the pose."""
    boxes: list[dict[str, Any]]
    """id, class_id, class, x1, y1, x2, y2, state ("moving", "static", "carried"), moving."""
    timings: dict[str, float]
    """Milliseconds: semantic, geometry, orb, tracking, map_wait, binding, total."""
    inliers: int
    keyframe: bool
    relocalised: bool
    new_map: bool
    backfilled: list[tuple[int, float, npt.NDArray[np.float64]]]

class Run:
    """A finished run."""
    trajectory: npt.NDArray[np.float64]
    """(N, 8): t tx ty tz qx qy qz qw (TUM order)."""
    keyframes: npt.NDArray[np.float64]
    map_points: npt.NDArray[np.float64]
    """(M, 3) positions, movers kept out."""
    loop_closed: bool
    maps_made: int
    """The first map, and one more each time tracking was lost for good."""
    maps_merged: int
    """Older maps merged into the current one when one of their places was seen again."""
    other_maps: dict[int, npt.NDArray[np.float64]]
    """Maps that never merged with the trajectory's: (N, 8) frames each, own frame of reference."""
    frames: int
    tracked: int
    def save_map(self, path: StrPath) -> int: ...
    def save_trajectory(self, path: StrPath) -> None: ...

class SourceFrame:
    index: int
    timestamp: float
    image: npt.NDArray[np.uint8] | None
    gray: npt.NDArray[np.uint8]
    depth: npt.NDArray[np.float32] | None
    right: npt.NDArray[np.uint8] | None

class Source:
    name: str
    path: str
    camera: Camera
    sensor: Sensor
    depth_scale: float
    fps: float
    baseline: float | None
    ground_truth: str | None
    boxes: str | None
    def __len__(self) -> int: ...
    def __getitem__(self, i: int) -> SourceFrame: ...
    def __iter__(self) -> Iterator[SourceFrame]: ...

class Slam:
    """Visual SLAM that stays accurate when the world moves. Used from one thread at a time."""
    camera: Camera
    sensor: Sensor
    def __init__(
        self, camera: Camera, sensor: Sensor = "rgbd", *, depth_scale: float = 5000.0,
        baseline: float | None = None, fps: float = 30.0,
        detector: Literal["yolox", "none"] = "yolox", model: StrPath | None = None,
        settings: Mapping[str, Any] | None = None, config: StrPath | None = None,
        sequential: bool = True, dynamic: bool = True,
    ) -> None: ...
    @staticmethod
    def for_source(
        source: Source, *, detector: Literal["yolox", "none"] = "yolox",
        model: StrPath | None = None, settings: Mapping[str, Any] | None = None,
        config: StrPath | None = None, sequential: bool = True, dynamic: bool = True,
    ) -> Slam: ...
    @staticmethod
    def from_map(
        path: StrPath, camera: Camera | None = None, sensor: Sensor | None = None, *,
        localize: bool = True, depth_scale: float = 5000.0, fps: float = 30.0,
        detector: Literal["yolox", "none"] = "yolox", model: StrPath | None = None,
        settings: Mapping[str, Any] | None = None, config: StrPath | None = None,
        sequential: bool = True, dynamic: bool = True,
    ) -> Slam: ...
    def track(
        self, image: npt.NDArray[np.uint8], timestamp: float,
        depth: npt.NDArray[np.uint16] | npt.NDArray[np.float32] | None = None,
        right: npt.NDArray[np.uint8] | None = None, boxes: BoxRows | None = None,
    ) -> Frame: ...
    def track_frame(self, frame: SourceFrame, boxes: BoxRows | None = None) -> Frame: ...
    def finish(self) -> Run: ...

def open(
    path: StrPath, *, kind: str | None = None, settings: StrPath | None = None,
    rgb_topic: str | None = None, depth_topic: str | None = None,
    right_topic: str | None = None, camera_info_topic: str | None = None,
) -> Source: ...

def synth(
    preset: str, out: StrPath, *, seed: int = 0, frames: int = 300,
    size: tuple[int, int] = (640, 480), noise: Literal["none", "kinect"] | None = None,
    textures: StrPath | None = None, stereo: bool = False, baseline: float = 0.1,
    masks: bool = False, path_offset: float = 0.0,
) -> dict[str, Any]: ...

def ate(
    gt: TrajectoryLike, est: TrajectoryLike, *, align: Literal["none", "se3", "sim3"] = "se3",
    format: Literal["tum", "kitti", "euroc"] = "tum", max_diff: float = 0.01, offset: float = 0.0,
) -> dict[str, float]: ...

def rpe(
    gt: TrajectoryLike, est: TrajectoryLike, *, delta: float = 1.0,
    delta_unit: Literal["f", "m", "s"] = "f", align: Literal["none", "se3", "sim3"] = "none",
    format: Literal["tum", "kitti", "euroc"] = "tum", max_diff: float = 0.01, offset: float = 0.0,
) -> dict[str, dict[str, float]]: ...
