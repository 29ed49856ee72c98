"""The Python package against the binary: the same frames give the same trajectory."""

from __future__ import annotations

import json

import numpy as np
import pytest

import stillpoint
from conftest import run_binary, tomllib


def track_folder(slam: stillpoint.Slam, f, n: int | None = None, boxes=None) -> stillpoint.Run:
    for i in range(len(f) if n is None else n):
        t, image, depth = f[i]
        slam.track(image, t, depth=depth, boxes=None if boxes is None else boxes(i))
    return slam.finish()


def test_trajectory_equals_the_binarys(binary, walking, folder, tmp_path):
    f = folder(walking)
    slam = stillpoint.Slam(f.camera, "rgbd", depth_scale=f.depth_scale, detector="none")
    run = track_folder(slam, f)
    ref = run_binary(binary, walking, tmp_path / "bin.txt", "--detector", "none")
    assert run.trajectory.shape == ref.shape == (len(f), 8)
    np.testing.assert_allclose(run.trajectory, ref, rtol=0, atol=1e-9)


def test_without_the_front_end_equals_no_dynamic(binary, walking, folder, tmp_path):
    f = folder(walking)
    slam = stillpoint.Slam(f.camera, depth_scale=f.depth_scale, dynamic=False)
    run = track_folder(slam, f)
    ref = run_binary(binary, walking, tmp_path / "bin.txt", "--no-dynamic")
    np.testing.assert_allclose(run.trajectory, ref, rtol=0, atol=1e-9)


def test_monocular_equals_the_binarys(binary, walking, folder, tmp_path):
    f = folder(walking)
    mono = tmp_path / "mono.toml"
    mono.write_text((walking / "settings.toml").read_text().replace('sensor = "rgbd"', 'sensor = "mono"'))
    slam = stillpoint.Slam(f.camera, "mono", detector="none")
    for i in range(len(f)):
        t, image, _ = f[i]
        slam.track(image, t)
    run = slam.finish()
    ref = run_binary(binary, walking, tmp_path / "bin.txt", "--detector", "none", "--settings", str(mono))
    assert len(ref) > 0
    np.testing.assert_allclose(run.trajectory, ref, rtol=0, atol=1e-9)


def test_stereo_equals_the_binarys(binary, stereo_pair, tmp_path):
    from PIL import Image

    s = tomllib.loads((stereo_pair / "settings_stereo.toml").read_text())
    c = s["camera"]
    cam = stillpoint.Camera(c["fx"], c["fy"], c["cx"], c["cy"], c["width"], c["height"])
    slam = stillpoint.Slam(cam, "stereo", baseline=s["bf"] / c["fx"], detector="none")
    times = [float(t) for t in (stereo_pair / "times.txt").read_text().split()]
    for i, t in enumerate(times):
        left = np.asarray(Image.open(stereo_pair / "image_0" / f"{i:06d}.png").convert("RGB"))
        right = np.asarray(Image.open(stereo_pair / "image_1" / f"{i:06d}.png").convert("L"))
        slam.track(left, t, right=right)
    run = slam.finish()
    ref = run_binary(binary, stereo_pair, tmp_path / "bin.txt", "--kind", "kitti", "--detector", "none")
    assert len(ref) == len(times)
    np.testing.assert_allclose(run.trajectory, ref, rtol=0, atol=1e-9)


def test_own_boxes_equal_the_gt_detector(binary, walking_halfsphere, folder, tmp_path):
    f = folder(walking_halfsphere)
    per_frame = {}
    for line in (walking_halfsphere / "boxes.jsonl").read_text().splitlines():
        rec = json.loads(line)
        per_frame[rec["frame"]] = [
            (b["class_id"], 1.0, b["bbox"]["x1"], b["bbox"]["y1"], b["bbox"]["x2"], b["bbox"]["y2"])
            for b in rec["boxes"]
        ]
    slam = stillpoint.Slam(f.camera, depth_scale=f.depth_scale, detector="none")
    culled = []

    def boxes(i):
        return np.array(per_frame[i], dtype=np.float64).reshape(-1, 6)

    for i in range(len(f)):
        t, image, depth = f[i]
        culled.append(int(slam.track(image, t, depth=depth, boxes=boxes(i)).dynamic.sum()))
    run = slam.finish()
    ref = run_binary(binary, walking_halfsphere, tmp_path / "bin.txt", "--detector", "gt")
    np.testing.assert_allclose(run.trajectory, ref, rtol=0, atol=1e-9)
    assert sum(culled) > 0, "the people's keypoints were culled"


def test_open_reads_what_pil_reads(walking, folder):
    f = folder(walking)
    src = stillpoint.open(walking)
    assert len(src) == len(f) and src.sensor == "rgbd" and src.depth_scale == f.depth_scale
    for i in (0, len(f) - 1):
        t, image, depth = f[i]
        fr = src[i]
        assert fr.timestamp == t
        np.testing.assert_array_equal(fr.image, image)
        np.testing.assert_array_equal(fr.depth, depth.astype(np.float32) / np.float32(f.depth_scale))
    assert [fr.index for fr in src] == list(range(len(f)))


def test_a_frame_reports_what_was_judged(walking_halfsphere):
    src = stillpoint.open(walking_halfsphere)
    slam = stillpoint.Slam.for_source(src, detector="none")
    frames = [slam.track_frame(fr) for fr in src]
    last = frames[-1]
    assert last.state == "ok" and last.pose.shape == (4, 4)
    np.testing.assert_allclose(last.pose[3], [0, 0, 0, 1])
    n = len(last.keypoints)
    assert last.keypoints.shape == (n, 2) and last.dynamic.shape == (n,) == last.matched.shape
    assert not (last.dynamic & last.matched).any(), "with depth a culled keypoint is never matched"
    for key in ("semantic", "geometry", "orb", "tracking", "binding", "total"):
        assert last.timings[key] >= 0
    run = slam.finish()
    assert run.tracked == len(src) and run.map_points.shape[1] == 3
    assert run.keyframes.shape[1] == 8 and len(run.keyframes) >= 2
    assert (run.maps_made, run.maps_merged, run.other_maps) == (1, 0, {})


def test_a_saved_map_is_localised_in(static_room, tmp_path):
    src = stillpoint.open(static_room)
    slam = stillpoint.Slam.for_source(src, dynamic=False)
    for fr in src:
        slam.track_frame(fr)
    run = slam.finish()
    size = run.save_map(tmp_path / "room.map")
    assert size > 0
    again = stillpoint.Slam.from_map(tmp_path / "room.map", localize=True, dynamic=False)
    assert again.camera.fx == src.camera.fx and again.sensor == "rgbd"
    poses = [again.track_frame(src[i]).pose for i in range(30, 40)]
    assert all(p is not None for p in poses)
    gt = {round(r[0], 4): r for r in run.trajectory}
    for i, p in zip(range(30, 40), poses):
        np.testing.assert_allclose(p[:3, 3], gt[round(src[i].timestamp, 4)][1:4], atol=0.01)


def test_yolox_finds_the_people(shared, walking_halfsphere):
    model = shared / "models" / "yolox_nano_480x640.onnx"
    src = stillpoint.open(walking_halfsphere)
    slam = stillpoint.Slam.for_source(src, detector="yolox", model=model)
    frames = [slam.track_frame(src[i]) for i in range(5)]
    people = [b for fr in frames for b in fr.boxes if b["class"] == "person"]
    assert people, "YOLOX saw no person in five frames with two walking"
    assert all(fr.state == "ok" for fr in frames)
