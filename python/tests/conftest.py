"""Fixtures of the Python package's tests: synthetic sequences made by stillpoint.synth and read
back with PIL/numpy, the `stillpoint` binary to compare with, and ../shared when it is there.

Environment: STILLPOINT_BIN (the binary; default the workspace's target/{debug,release}),
STILLPOINT_SHARED (default ../shared beside the repository), STILLPOINT_FAIL_ON_SKIP=1 (CI: a
skipped test is a failure)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

import stillpoint

REPO = Path(__file__).resolve().parents[2]


def pytest_sessionfinish(session, exitstatus):
    if os.environ.get("STILLPOINT_FAIL_ON_SKIP") != "1":
        return
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    skipped = reporter.stats.get("skipped", []) if reporter else []
    if skipped:
        for r in skipped:
            print(f"SKIPPED (a failure in CI): {r.nodeid}: {r.longrepr}")
        session.exitstatus = 1


@pytest.fixture(scope="session")
def binary() -> Path:
    env = os.environ.get("STILLPOINT_BIN")
    candidates = [Path(env)] if env else [
        REPO / "target" / "debug" / "stillpoint",
        REPO / "target" / "release" / "stillpoint",
    ]
    for c in candidates:
        if c.is_file():
            return c
    pytest.skip(f"no stillpoint binary (looked at {', '.join(map(str, candidates))}; "
                "build it with `cargo build` or set STILLPOINT_BIN)")


@pytest.fixture(scope="session")
def shared() -> Path:
    p = Path(os.environ.get("STILLPOINT_SHARED", REPO.parent / "shared"))
    if not (p / "data").is_dir():
        pytest.skip(f"{p}/data not found")
    return p


@pytest.fixture(scope="session")
def walking(tmp_path_factory) -> Path:
    """60 frames of walking_xyz with people walking (RGB-D, boxes, ground truth)."""
    out = tmp_path_factory.mktemp("seq") / "walking_xyz"
    stillpoint.synth("walking_xyz", out, seed=3, frames=60)
    return out


@pytest.fixture(scope="session")
def static_room(tmp_path_factory) -> Path:
    """60 frames of a room where nothing moves."""
    out = tmp_path_factory.mktemp("seq") / "static"
    stillpoint.synth("static", out, seed=2, frames=60)
    return out


@pytest.fixture(scope="session")
def stereo_pair(tmp_path_factory) -> Path:
    """40 frames of walking_xyz with a rectified pair 0.1 m apart (KITTI layout beside TUM's)."""
    out = tmp_path_factory.mktemp("seq") / "walking_stereo"
    stillpoint.synth("walking_xyz", out, seed=6, frames=40, stereo=True, baseline=0.1)
    return out


@pytest.fixture(scope="session")
def walking_halfsphere(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("seq") / "walking_halfsphere"
    stillpoint.synth("walking_halfsphere", out, seed=1, frames=40)
    return out


class Folder:
    """A stillpoint.synth folder read with PIL and numpy (not through stillpoint.open)."""

    def __init__(self, path: Path):
        from PIL import Image

        self.path = path
        s = tomllib.loads((path / "settings.toml").read_text())
        c = s["camera"]
        self.camera = stillpoint.Camera(c["fx"], c["fy"], c["cx"], c["cy"], c["width"], c["height"])
        self.depth_scale = s["depth_factor"]
        rows = lambda name: [  # noqa: E731
            line.split() for line in (path / name).read_text().splitlines()
            if line.strip() and not line.startswith("#")
        ]
        depth = {float(t): f for t, f in rows("depth.txt")}
        self.frames = [(float(t), f, depth[float(t)]) for t, f in rows("rgb.txt")]
        self._image = Image

    def __len__(self):
        return len(self.frames)

    def __getitem__(self, i):
        t, rgb, depth = self.frames[i]
        image = np.asarray(self._image.open(self.path / rgb).convert("RGB"))
        d = np.asarray(self._image.open(self.path / depth)).astype(np.uint16)
        return t, image, d


@pytest.fixture
def folder():
    return Folder


def run_binary(binary: Path, seq: Path, out: Path, *args: str) -> np.ndarray:
    """`stillpoint run` (a file run: sequential) and its trajectory as (N, 8) rows."""
    subprocess.run(
        [str(binary), "run", "--dataset", str(seq), "--out", str(out), *args],
        check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )
    return np.loadtxt(out, ndmin=2)
