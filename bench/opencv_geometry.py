#!/usr/bin/env python3
"""The paper's geometry module with OpenCV (as DS-SLAM / the authors' code calls it), timed per
frame, to compare with `stillpoint bench dynamic` on the same sequence.

usage: python3 bench/opencv_geometry.py DATASET_DIR [--max-frames N] [--json]

Same work per frame: goodFeaturesToTrack(1000, 0.01, 8, block 3, Harris k 0.04), cornerSubPix
(10x10, 20 it, 0.03), calcOpticalFlowPyrLK (22x22, 5 levels, 20 it, 0.01), border 5 px and 3x3
SAD 2120 checks, findFundamentalMat(RANSAC, 0.1, 0.99), epipolar distance > 1 px. OpenCV is
pinned to one thread so the comparison is core for core.
"""
import argparse
import json
import os
import statistics
import time

import cv2
import numpy as np


def frames(dataset):
    with open(os.path.join(dataset, "rgb.txt")) as f:
        for line in f:
            line = line.strip()
            if line and not line.startswith("#"):
                t, name = line.split()[:2]
                yield float(t), os.path.join(dataset, name)


def geometry(prev, cur):
    stages = {}
    t0 = time.perf_counter()
    pts = cv2.goodFeaturesToTrack(prev, 1000, 0.01, 8, mask=None, blockSize=3,
                                  useHarrisDetector=True, k=0.04)
    if pts is None:
        return stages, 0, 0
    cv2.cornerSubPix(prev, pts, (10, 10), (-1, -1),
                     (cv2.TERM_CRITERIA_MAX_ITER | cv2.TERM_CRITERIA_EPS, 20, 0.03))
    t1 = time.perf_counter()
    nxt, status, _ = cv2.calcOpticalFlowPyrLK(
        prev, cur, pts, None, winSize=(22, 22), maxLevel=5,
        criteria=(cv2.TERM_CRITERIA_MAX_ITER | cv2.TERM_CRITERIA_EPS, 20, 0.01))
    t2 = time.perf_counter()
    h, w = prev.shape
    p1, p2 = [], []
    for (a, b, ok) in zip(pts.reshape(-1, 2), nxt.reshape(-1, 2), status.reshape(-1)):
        if not ok:
            continue
        if (a[0] < 5 or a[1] < 5 or a[0] > w - 6 or a[1] > h - 6 or
                b[0] < 5 or b[1] < 5 or b[0] > w - 6 or b[1] > h - 6):
            continue
        x1, y1, x2, y2 = int(a[0]), int(a[1]), int(b[0]), int(b[1])
        sad = np.abs(prev[y1 - 1:y1 + 2, x1 - 1:x1 + 2].astype(np.int32) -
                     cur[y2 - 1:y2 + 2, x2 - 1:x2 + 2].astype(np.int32)).sum()
        if sad > 2120:
            continue
        p1.append(a)
        p2.append(b)
    t3 = time.perf_counter()
    outliers = 0
    if len(p1) >= 8:
        p1, p2 = np.float32(p1), np.float32(p2)
        F, _ = cv2.findFundamentalMat(p1, p2, cv2.FM_RANSAC, 0.1, 0.99)
        if F is not None and F.shape == (3, 3):
            ones = np.ones((len(p1), 1), np.float32)
            lines = (F @ np.hstack([p1, ones]).T).T
            d = np.abs((np.hstack([p2, ones]) * lines).sum(1)) / np.sqrt(
                lines[:, 0] ** 2 + lines[:, 1] ** 2)
            outliers = int((d > 1.0).sum())
    t4 = time.perf_counter()
    stages = {"corners_ms": (t1 - t0) * 1e3, "lk_ms": (t2 - t1) * 1e3,
              "checks_ms": (t3 - t2) * 1e3, "model_ms": (t4 - t3) * 1e3}
    return stages, len(p1), outliers


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dataset")
    ap.add_argument("--max-frames", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    prev = None
    totals, per_stage = [], {}
    for i, (_, path) in enumerate(frames(args.dataset)):
        if args.max_frames and i >= args.max_frames:
            break
        gray = cv2.cvtColor(cv2.imread(path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2GRAY)
        if prev is not None:
            stages, _, _ = geometry(prev, gray)
            totals.append(sum(stages.values()))
            for k, v in stages.items():
                per_stage.setdefault(k, []).append(v)
        prev = gray
    report = {"frames": len(totals), "opencv": cv2.__version__,
              "geometry_ms_mean": statistics.mean(totals),
              "geometry_ms_median": statistics.median(totals),
              "stage_ms_mean": {k: statistics.mean(v) for k, v in per_stage.items()}}
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        s = report["stage_ms_mean"]
        print(f"OpenCV {report['opencv']} geometry module: mean {report['geometry_ms_mean']:.2f} ms, "
              f"median {report['geometry_ms_median']:.2f} ms per frame over {report['frames']} frames "
              f"(corners {s['corners_ms']:.2f}, LK {s['lk_ms']:.2f}, checks {s['checks_ms']:.2f}, "
              f"model {s['model_ms']:.2f})")


if __name__ == "__main__":
    main()
