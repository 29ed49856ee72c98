#!/usr/bin/env python3
"""OpenCV reference for `stillpoint bench features` (issue 4).

Two modes, both print JSON on stdout:

  speed IMAGES... [--repeat N] [--threads T]
      ms per frame (median, p90) of ORB (1000 features, ORB-SLAM settings), goodFeaturesToTrack
      + cornerSubPix (paper settings), and calcOpticalFlowPyrLK of those corners into the next
      image (paper settings), over all images x repeats. Image i is tracked into image i+1
      (the last into the first).

  serve IMAGES... [--threads T]
      the speed measurement one round at a time: prints a JSON header line, then for every
      `round` line on stdin runs every image once and prints that round's per-frame ms as one
      JSON line. `stillpoint bench features` uses it to alternate its rounds with OpenCV's.

  quality PREV CUR [PREV CUR ...] [--dump FILE]
      per pair: ORB matches (brute force, ratio 0.8, mutual), fundamental RANSAC inliers
      (1 px, 0.99) and their ratio, in the input order and as the mean over 20 shuffled orders
      (findFundamentalMat's sampler has a fixed seed, so one run is one draw: on the KITTI
      sequence pair the input order gives 0.720 and the mean is 0.661); the same with
      ORB-SLAM's rotation-consistency check added to the matcher ("rot", the matcher stillpoint
      uses); LK points whose forward-backward error is below 0.5 px. --dump writes the matched
      points, so `cargo run --release -p stillpoint-features --example match_quality` can score
      them with stillpoint's RANSAC.

Needs opencv-python-headless (pip install opencv-python-headless==5.0.0.93 numpy).
"""

import argparse
import json
import sys
import time

import cv2
import numpy as np

ORB = dict(nfeatures=1000, scaleFactor=1.2, nlevels=8, edgeThreshold=19, patchSize=31,
           fastThreshold=20)
# OpenCV's own defaults but the feature count (edgeThreshold 31: fewer border pixels to scan)
ORB_DEFAULT = dict(nfeatures=1000, scaleFactor=1.2, nlevels=8, edgeThreshold=31, firstLevel=0,
                   WTA_K=2, scoreType=cv2.ORB_HARRIS_SCORE, patchSize=31, fastThreshold=20)
GFTT = dict(maxCorners=1000, qualityLevel=0.01, minDistance=8, blockSize=3,
            useHarrisDetector=True, k=0.04)
SUBPIX = dict(winSize=(10, 10), zeroZone=(-1, -1),
              criteria=(cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 20, 0.03))
LK = dict(winSize=(22, 22), maxLevel=5,
          criteria=(cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 20, 0.01))


def gray(path):
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        sys.exit(f"{path}: cannot read image")
    if img.dtype == np.uint16:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    return img


def stats(xs):
    xs = sorted(xs)
    return {"median": xs[len(xs) // 2], "p90": xs[min(len(xs) - 1, int(len(xs) * 0.9))],
            "n": len(xs)}


def corners(img):
    pts = cv2.goodFeaturesToTrack(img, **GFTT)
    if pts is None:
        return np.zeros((0, 1, 2), np.float32)
    cv2.cornerSubPix(img, pts, **SUBPIX)
    return pts


def one_round(imgs, orbs, t, counts):
    """Every image once: ORB (ours: edgeThreshold 19; OpenCV's defaults: 31),
    goodFeaturesToTrack + cornerSubPix, LK into the next image."""
    orb, orb_default = orbs
    for i, img in enumerate(imgs):
        nxt = imgs[(i + 1) % len(imgs)]
        if nxt.shape != img.shape:
            nxt = img
        td = time.perf_counter()
        orb_default.detectAndCompute(img, None)
        t["orb_default"].append((time.perf_counter() - td) * 1e3)
        t0 = time.perf_counter()
        kps, _ = orb.detectAndCompute(img, None)
        t1 = time.perf_counter()
        pts = cv2.goodFeaturesToTrack(img, **GFTT)
        t2 = time.perf_counter()
        if pts is None:
            pts = np.zeros((0, 1, 2), np.float32)
        else:
            cv2.cornerSubPix(img, pts, **SUBPIX)
        t3 = time.perf_counter()
        if len(pts):
            _, st, _ = cv2.calcOpticalFlowPyrLK(img, nxt, pts, None, **LK)
            counts["tracked"].append(int(st.sum()))
        t4 = time.perf_counter()
        counts["features"].append(len(kps))
        counts["corners"].append(len(pts))
        ms = lambda a, b: (b - a) * 1e3
        t["orb"].append(ms(t0, t1))
        t["gftt"].append(ms(t1, t2))
        t["subpix"].append(ms(t2, t3))
        t["harris_subpix"].append(ms(t1, t3))
        t["lk"].append(ms(t3, t4))
        t["harris_lk"].append(ms(t1, t4))


def new_times():
    return {"orb": [], "orb_default": [], "gftt": [], "subpix": [], "harris_subpix": [],
            "lk": [], "harris_lk": []}


def summary(t, counts):
    out = {k: stats(v) for k, v in t.items() if v}
    out["opencv"] = cv2.__version__
    out["threads"] = cv2.getNumThreads()
    for k in ("features", "corners", "tracked"):
        out[k + "_mean"] = float(np.mean(counts[k])) if counts[k] else 0.0
    return out


def speed(args):
    cv2.setNumThreads(args.threads)
    imgs = [gray(p) for p in args.images]
    orbs = (cv2.ORB_create(**ORB), cv2.ORB_create(**ORB_DEFAULT))
    t = new_times()
    counts = {"features": [], "corners": [], "tracked": []}
    for _ in range(args.repeat):
        one_round(imgs, orbs, t, counts)
    print(json.dumps(summary(t, counts)))


def serve(args):
    """One JSON line per `round` line read on stdin (per-frame ms of that round), so the caller
    can interleave its own rounds with OpenCV's and load changes hit both sides alike."""
    cv2.setNumThreads(args.threads)
    imgs = [gray(p) for p in args.images]
    orbs = (cv2.ORB_create(**ORB), cv2.ORB_create(**ORB_DEFAULT))
    print(json.dumps({"opencv": cv2.__version__, "threads": cv2.getNumThreads()}), flush=True)
    for line in sys.stdin:
        if line.strip() != "round":
            break
        t = new_times()
        counts = {"features": [], "corners": [], "tracked": []}
        one_round(imgs, orbs, t, counts)
        print(json.dumps({"times": t, "counts": counts}), flush=True)


def rotation_consistent(k1, k2, matches, n_bins=30):
    """ORB-SLAM's rotation check: keep matches in the three biggest bins of the keypoint-angle
    change (2nd and 3rd only if they hold at least 10 % of the biggest), as stillpoint's
    RotationHistogram."""
    bins = [[] for _ in range(n_bins)]
    for j, m in enumerate(matches):
        rot = (k1[m.queryIdx].angle - k2[m.trainIdx].angle) % 360.0
        bins[int(round(rot * n_bins / 360.0)) % n_bins].append(j)
    order = sorted(range(n_bins), key=lambda b: -len(bins[b]))
    keep = [order[0]]
    for b in order[1:3]:
        if not bins[b] or len(bins[b]) < 0.1 * len(bins[order[0]]):
            break
        keep.append(b)
    ok = {j for b in keep for j in bins[b]}
    return [m for j, m in enumerate(matches) if j in ok]


def fundamental_inliers(p1, p2):
    if len(p1) < 8:
        return 0
    _, mask = cv2.findFundamentalMat(p1, p2, cv2.FM_RANSAC, 1.0, 0.99)
    return int(mask.sum()) if mask is not None else 0


def ransac_scores(k1, k2, matches, rng):
    """Inliers in the input order, and the mean inlier ratio over 20 shuffled orders."""
    p1 = np.float32([k1[m.queryIdx].pt for m in matches]).reshape(-1, 2)
    p2 = np.float32([k2[m.trainIdx].pt for m in matches]).reshape(-1, 2)
    first = fundamental_inliers(p1, p2)
    ratios = [first / max(1, len(matches))]
    for _ in range(19):
        order = rng.permutation(len(matches))
        ratios.append(fundamental_inliers(p1[order], p2[order]) / max(1, len(matches)))
    return first, float(np.mean(ratios)), np.hstack([p1, p2]).tolist()


def quality(args):
    if len(args.images) % 2:
        sys.exit("quality needs pairs of images")
    orb = cv2.ORB_create(**ORB)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    rng = np.random.default_rng(0)
    res, dump = [], []
    for a, b in zip(args.images[::2], args.images[1::2]):
        i1, i2 = gray(a), gray(b)
        k1, d1 = orb.detectAndCompute(i1, None)
        k2, d2 = orb.detectAndCompute(i2, None)
        fwd = bf.knnMatch(d1, d2, k=2)
        back = {m[0].queryIdx: m[0].trainIdx for m in bf.knnMatch(d2, d1, k=1) if m}
        good = [m[0] for m in fwd if len(m) == 2 and m[0].distance <= 100
                and m[0].distance < 0.8 * m[1].distance and back.get(m[0].trainIdx) == m[0].queryIdx]
        inl, mean_ratio, pts = ransac_scores(k1, k2, good, rng)
        rot = rotation_consistent(k1, k2, good)
        rot_inl, rot_mean, rot_pts = ransac_scores(k1, k2, rot, rng)
        dump.append({"prev": a, "variant": "bf", "pts": pts})
        dump.append({"prev": a, "variant": "bf+rot", "pts": rot_pts})
        corners_1 = corners(i1)
        n_fb = 0
        if len(corners_1) and i1.shape == i2.shape:
            nxt, st, _ = cv2.calcOpticalFlowPyrLK(i1, i2, corners_1, None, **LK)
            back_pts, st2, _ = cv2.calcOpticalFlowPyrLK(i2, i1, nxt, None, **LK)
            fb = np.linalg.norm((back_pts - corners_1).reshape(-1, 2), axis=1)
            ok = (st.ravel() == 1) & (st2.ravel() == 1) & (fb < 0.5)
            n_fb = int(ok.sum())
        res.append({"prev": a, "cur": b, "features": [len(k1), len(k2)], "matches": len(good),
                    "inliers": inl, "inlier_ratio": inl / max(1, len(good)),
                    "inlier_ratio_mean20": mean_ratio,
                    "rot_matches": len(rot), "rot_inliers": rot_inl,
                    "rot_inlier_ratio_mean20": rot_mean,
                    "corners": len(corners_1), "lk_fb_below_0_5px": n_fb})
    if args.dump:
        with open(args.dump, "w") as f:
            json.dump(dump, f)
    print(json.dumps({"opencv": cv2.__version__, "pairs": res}))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("mode", choices=["speed", "serve", "quality"])
    ap.add_argument("images", nargs="+")
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--dump", help="quality: write the matched points (JSON) to this file")
    ap.add_argument("--threads", type=int, default=1,
                    help="cv2.setNumThreads (1 = single-threaded, as stillpoint's front-end)")
    args = ap.parse_args()
    {"speed": speed, "serve": serve, "quality": quality}[args.mode](args)


if __name__ == "__main__":
    main()
