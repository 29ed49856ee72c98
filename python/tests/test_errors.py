"""Each bad input raises one clear error naming the argument, key or file."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import stillpoint

CAM = stillpoint.Camera(535.4, 539.2, 320.1, 247.6, 640, 480)
RGB = np.zeros((480, 640, 3), np.uint8)
DEPTH = np.zeros((480, 640), np.uint16)


def slam(**kw):
    return stillpoint.Slam(CAM, kw.pop("sensor", "rgbd"), detector="none", **kw)


@pytest.mark.parametrize(
    "kwargs,message",
    [
        (dict(image=RGB.astype(np.float32), timestamp=0.0, depth=DEPTH), "image: expected a uint8 array of shape (480, 640, 3)"),
        (dict(image=RGB[:100], timestamp=0.0, depth=DEPTH), "image: expected a uint8 array"),
        (dict(image=[[1, 2]], timestamp=0.0, depth=DEPTH), "got list"),
        (dict(image=RGB, timestamp=0.0), "depth: an RGB-D Slam needs a depth image"),
        (dict(image=RGB, timestamp=0.0, depth=DEPTH.astype(np.int32)), "depth: expected a uint16"),
        (dict(image=RGB, timestamp=float("nan"), depth=DEPTH), "timestamp: must be finite"),
        (dict(image=RGB, timestamp=0.0, depth=DEPTH, right=RGB), "right: a rgbd Slam takes no right image"),
        (dict(image=RGB, timestamp=0.0, depth=DEPTH, boxes=[(0, 1.0, 10, 10)]), "boxes[0]: expected 6 values"),
        (dict(image=RGB, timestamp=0.0, depth=DEPTH, boxes=[(0, 2.0, 1, 1, 5, 5)]), "boxes[0]: score must be within 0..1"),
        (dict(image=RGB, timestamp=0.0, depth=DEPTH, boxes="person"), "boxes: expected rows"),
    ],
)
def test_track_names_the_bad_argument(kwargs, message):
    with pytest.raises(ValueError, match=None) as e:
        slam().track(**kwargs)
    assert message in str(e.value)


def test_timestamps_must_increase():
    s = slam()
    s.track(RGB, 1.0, depth=DEPTH)
    with pytest.raises(ValueError, match=r"timestamp: 1.0 is not after the previous frame's 1.0"):
        s.track(RGB, 1.0, depth=DEPTH)


def test_monocular_takes_no_depth_and_stereo_needs_a_baseline():
    with pytest.raises(ValueError, match="depth: a mono Slam takes no depth image"):
        slam(sensor="mono").track(RGB, 0.0, depth=DEPTH)
    with pytest.raises(ValueError, match="baseline: a stereo Slam needs the baseline"):
        slam(sensor="stereo")
    with pytest.raises(ValueError, match="right: a stereo Slam needs the right image"):
        slam(sensor="stereo", baseline=0.1).track(RGB, 0.0)


def test_bad_construction():
    with pytest.raises(ValueError, match='sensor: expected "rgbd", "stereo" or "mono", got "lidar"'):
        stillpoint.Slam(CAM, "lidar")
    with pytest.raises(ValueError, match="fx: a focal length in pixels must be positive"):
        stillpoint.Camera(0, 1, 1, 1, 640, 480)
    with pytest.raises(ValueError, match='detector: expected "yolox" or "none"'):
        stillpoint.Slam(CAM, detector="maskrcnn")
    with pytest.raises(ValueError, match="depth_scale: depth units per metre must be positive"):
        stillpoint.Slam(CAM, depth_scale=0, detector="none")


def test_settings_errors_name_the_key_and_the_file(tmp_path):
    with pytest.raises(stillpoint.Error, match="front_end.no_such_key"):
        slam(settings={"front_end.no_such_key": 1})
    with pytest.raises(ValueError, match="None is no value"):
        slam(settings={"orb.n_features": None})
    bad = tmp_path / "mine.toml"
    bad.write_text("[orb]\nn_features = 'many'\n")
    with pytest.raises(stillpoint.Error, match="mine.toml"):
        slam(config=bad)
    with pytest.raises(stillpoint.Error, match="missing.toml"):
        slam(config=tmp_path / "missing.toml")
    # numbers no setting takes: not a number, negative, a ratio over 1, a frame rate of 0
    with pytest.raises(stillpoint.Error, match="`slam.fps`: not a number"):
        slam(settings={"slam.fps": float("nan")})
    with pytest.raises(stillpoint.Error, match="`slam.mono_init.window_px`: -10 is negative"):
        slam(settings={"slam.mono_init.window_px": -10})
    with pytest.raises(stillpoint.Error, match="`front_end.dynamic.judge.ata_ratio`: 1.5 is over 1"):
        slam(settings={"front_end.dynamic.judge.ata_ratio": 1.5})
    with pytest.raises(stillpoint.Error, match="`slam.fps` = 0: frames per second must be positive"):
        slam(settings={"slam.fps": 0})
    s = slam(settings={"orb.n_features": 700, "front_end.dynamic.world.enabled": False})
    assert len(s.track(RGB, 0.0, depth=DEPTH).keypoints) <= 700


def test_files_that_cannot_be_read(tmp_path):
    with pytest.raises(stillpoint.Error, match="no_such_folder"):
        stillpoint.open(tmp_path / "no_such_folder")
    (tmp_path / "rec.mcap").write_bytes(b"")
    with pytest.raises(ValueError, match="rgb_topic: .*rec.mcap is a ROS recording"):
        stillpoint.open(tmp_path / "rec.mcap")
    (tmp_path / "broken.map").write_bytes(b"not a map")
    with pytest.raises(stillpoint.Error, match="broken.map"):
        stillpoint.Slam.from_map(tmp_path / "broken.map")
    with pytest.raises(stillpoint.Error, match="no_model.onnx"):
        stillpoint.Slam(CAM, detector="yolox", model=tmp_path / "no_model.onnx")
    with pytest.raises(stillpoint.Error, match="missing.txt"):
        stillpoint.eval.ate(tmp_path / "missing.txt", tmp_path / "missing.txt")
    with pytest.raises(ValueError, match=r"est: expected an \(N, 8\) float64 array"):
        gt = np.array([[t, 0, 0, 0, 0, 0, 0, 1] for t in range(3)], dtype=np.float64)
        stillpoint.eval.ate(gt, np.zeros((3, 7)))
    with pytest.raises(ValueError, match="preset: unknown"):
        stillpoint.synth("no_such_preset", tmp_path / "x")


def test_no_model_anywhere_says_how_to_get_one(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("STILLPOINT_MODEL", raising=False)
    monkeypatch.setenv("STILLPOINT_MODELS", str(tmp_path))
    with pytest.raises(stillpoint.Error, match="STILLPOINT_MODELS") as e:
        stillpoint.Slam(CAM, detector="yolox")
    assert "yolox_nano" in str(e.value)


def test_a_finished_slam_takes_no_frames():
    s = slam()
    s.finish()
    with pytest.raises(stillpoint.Error, match="this Slam has finished"):
        s.track(RGB, 0.0, depth=DEPTH)
    with pytest.raises(stillpoint.Error, match="already finished"):
        s.finish()


def test_ctrl_c_interrupts_a_long_call(tmp_path):
    # The child takes Ctrl-C as a terminal gives it: a shell's background job (a CI run
    # started with `&`) passes SIGINT on ignored, and Python then installs no handler for it.
    child = subprocess.Popen(
        [sys.executable, "-c", (
            "import signal, stillpoint, sys\n"
            "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "try:\n"
            "    print('started', flush=True)\n"
            f"    stillpoint.synth('walking_xyz', {str(tmp_path / 'seq')!r}, frames=100000)\n"
            "except KeyboardInterrupt:\n"
            "    print('interrupted', flush=True)\n"
        )],
        stdout=subprocess.PIPE, text=True,
    )
    assert child.stdout.readline().strip() == "started"
    child.send_signal(2)  # SIGINT, as Ctrl-C sends
    out, _ = child.communicate(timeout=120)
    assert out.strip() == "interrupted" and child.returncode == 0
