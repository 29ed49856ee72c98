"""Batch runs: every sequence x every combination of settings, one run per task.

    python -m stillpoint.batch --sequences seq_a seq_b --set slam.loop_closing.enabled=true,false \\
        --out results/ --engine ray [--address ray://host:10001] [--workers 2] [--cpus-per-run 1]

Each run is sequential (local mapping inline: the same trajectory however busy the machine is),
so a row equals a single run of the same settings. With `--engine ray` each run is a Ray task
with `num_cpus` = `--cpus-per-run` in a fresh worker process (`max_calls=1`: its peak memory is
its own); without `--address` a local Ray is started with `--workers` x `--cpus-per-run` CPUs.
`--engine local` does the same with a process pool (spawn, one run per process).

Sequence paths must be readable where the runs execute (on a remote cluster: shared storage).
Writes `runs.csv` and `runs.parquet` (sequence, settings, ATE, RPE, frames, tracked, ms a frame,
peak memory) and each run's TUM trajectory under `trajectories/`, and prints the table.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import os
import re
import sys
import time
from pathlib import Path

COLUMNS = [
    "sequence",
    "settings",
    "detector",
    "ate_m",
    "rpe_translation_m",
    "rpe_rotation_deg",
    "frames",
    "tracked",
    "ms_per_frame",
    "peak_memory_mb",
    "trajectory",
    "error",
]


def parse_set(arg: str) -> tuple[str, list[str]]:
    """`KEY=V1,V2` -> (KEY, [V1, V2]). A value holding a comma goes in brackets: `k=[1,2]`."""
    key, sep, values = arg.partition("=")
    if not sep or not key.strip() or not values.strip():
        raise argparse.ArgumentTypeError(f"--set {arg!r}: expected KEY=V1,V2,...")
    parts, depth, cur = [], 0, ""
    for ch in values:
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
            continue
        if ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
        cur += ch
    parts.append(cur)
    return key.strip(), [p.strip() for p in parts if p.strip()]


def grid(sets: list[tuple[str, list[str]]]) -> list[dict[str, str]]:
    """Every combination of the settings' values (one empty combination without --set)."""
    keys = [k for k, _ in sets]
    return [dict(zip(keys, combo)) for combo in itertools.product(*(v for _, v in sets))]


def slug(sequence: str, settings: dict[str, str]) -> str:
    text = "__".join([Path(sequence).name] + [f"{k}={v}" for k, v in settings.items()])
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", text)


def run_one(
    sequence: str,
    settings: dict[str, str],
    detector: str,
    model: str | None,
    frames: int | None,
    cpus: int,
) -> dict:
    """One sequential run of `sequence` with `settings`: a row of the table, and the trajectory
    under "poses" (written by the driver, so a remote cluster's runs land in `--out` too). Runs
    in its own process (a Ray worker or a pool process), so the peak memory is the run's."""
    import resource

    import stillpoint

    row = {c: None for c in COLUMNS}
    row.update(sequence=sequence, settings=json.dumps(settings, sort_keys=True), detector=detector)
    try:
        source = stillpoint.open(sequence)
        values = dict(settings)
        # The run's own threads: the detector's intra-op threads follow the task's CPUs.
        values.setdefault("detect.threads", str(cpus))
        slam = stillpoint.Slam.for_source(
            source,
            detector="none" if detector == "off" else detector,
            dynamic=detector != "off",
            model=model,
            settings=values,
            sequential=True,
        )
        n = len(source) if frames is None else min(frames, len(source))
        t0 = time.perf_counter()
        for i in range(n):
            slam.track_frame(source[i])
        run = slam.finish()
        seconds = time.perf_counter() - t0
        row.update(frames=n, tracked=int(run.tracked), ms_per_frame=1e3 * seconds / max(n, 1))
        row["poses"] = run.trajectory.tolist()
        gt = source.ground_truth
        if gt is not None and len(run.trajectory) >= 2:
            align = "sim3" if source.sensor == "mono" else "se3"
            row["ate_m"] = stillpoint.eval.ate(str(gt), run.trajectory, align=align)["rmse"]
            rpe = stillpoint.eval.rpe(str(gt), run.trajectory)
            row["rpe_translation_m"] = rpe["translation"]["rmse"]
            row["rpe_rotation_deg"] = rpe["rotation_deg"]["rmse"]
    except Exception as e:  # noqa: BLE001  (a failed run is a row with its error, not a lost batch)
        row["error"] = f"{type(e).__name__}: {e}"
    # ru_maxrss is KiB on Linux.
    row["peak_memory_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return row


def run_on_ray(tasks: list[tuple], address: str | None, workers: int, cpus: int) -> list[dict]:
    if address:
        # Ray 2.60's `ray start --head` turns token authentication on when a token exists
        # (~/.ray/auth_token, written by any earlier local Ray), but a client sends it only when
        # RAY_AUTH_MODE says so, and Ray reads that on import: without it a `ray://` connection
        # times out.
        token_file = os.environ.get("RAY_AUTH_TOKEN_PATH", os.path.expanduser("~/.ray/auth_token"))
        if "RAY_AUTH_MODE" not in os.environ and (
            "RAY_AUTH_TOKEN" in os.environ or os.path.isfile(token_file)
        ):
            os.environ["RAY_AUTH_MODE"] = "token"
    try:
        import ray
    except ImportError as e:
        raise SystemExit(
            "--engine ray needs Ray: pip install 'stillpoint-slam[batch]' (or use --engine local)"
        ) from e
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        ray.init(num_cpus=workers * cpus, include_dashboard=False, log_to_driver=False)
    try:
        # A fresh worker per task (max_calls=1): memory figures are the run's own.
        remote = ray.remote(num_cpus=cpus, max_calls=1)(run_one)
        return ray.get([remote.remote(*t) for t in tasks])
    finally:
        ray.shutdown()


def run_locally(tasks: list[tuple], workers: int) -> list[dict]:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    kwargs = {"max_workers": workers, "mp_context": multiprocessing.get_context("spawn")}
    if sys.version_info >= (3, 11):
        kwargs["max_tasks_per_child"] = 1
    with ProcessPoolExecutor(**kwargs) as pool:
        return list(pool.map(run_one, *zip(*tasks)))


def write_trajectories(rows: list[dict], out: Path) -> None:
    """Each run's poses as a TUM file under out/trajectories; the row names it."""
    folder = out / "trajectories"
    folder.mkdir(parents=True, exist_ok=True)
    for r in rows:
        poses = r.pop("poses", None)
        if poses is None:
            continue
        path = folder / f"{slug(r['sequence'], json.loads(r['settings']))}.txt"
        with open(path, "w") as f:
            f.write("# timestamp tx ty tz qx qy qz qw\n")
            f.writelines(" ".join(repr(v) for v in p) + "\n" for p in poses)
        r["trajectory"] = str(path)


def write_table(rows: list[dict], out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "runs.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        print("pyarrow is not installed: runs.parquet not written", file=sys.stderr)
        return
    pq.write_table(pa.Table.from_pylist(rows), out / "runs.parquet")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m stillpoint.batch", description=__doc__.split("\n\n")[0]
    )
    p.add_argument("--sequences", nargs="+", required=True, help="sequence folders (or files)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        type=parse_set,
        metavar="KEY=V1,V2",
        help="a setting and the values to run it with (repeatable: the runs take every combination)",
    )
    p.add_argument("--out", required=True, type=Path, help="folder for the table and trajectories")
    p.add_argument("--engine", choices=["ray", "local"], default="ray")
    p.add_argument("--address", help="a running Ray cluster (ray://host:10001 or host:port)")
    p.add_argument("--workers", type=int, default=2, help="runs at once without --address")
    p.add_argument("--cpus-per-run", type=int, default=1, help="CPUs a run takes (its threads)")
    p.add_argument(
        "--detector", default="yolox", choices=["yolox", "none", "off"],
        help="yolox, none (motion check only) or off (no dynamic front-end)",
    )
    p.add_argument("--model", help="YOLOX ONNX file (default: $STILLPOINT_MODELS, ../shared/models)")
    p.add_argument("--frames", type=int, help="only the first N frames of each sequence")
    p.add_argument("--json", action="store_true", help="print the rows as JSON")
    a = p.parse_args(argv)
    if a.workers < 1 or a.cpus_per_run < 1:
        p.error("--workers and --cpus-per-run must be at least 1")
    if a.address and a.engine != "ray":
        p.error("--address is for --engine ray")
    for s in a.sequences:
        if not os.path.exists(s):
            p.error(f"--sequences: {s}: no such file or folder")
    out = a.out.resolve()
    tasks = [
        (str(Path(s).resolve()), combo, a.detector, a.model, a.frames, a.cpus_per_run)
        for s in a.sequences
        for combo in grid(a.set)
    ]
    if a.engine == "ray":
        rows = run_on_ray(tasks, a.address, a.workers, a.cpus_per_run)
    else:
        rows = run_locally(tasks, a.workers)
    write_trajectories(rows, out)
    write_table(rows, out)
    if a.json:
        print(json.dumps(rows, indent=1))
    else:
        print("sequence\tsettings\tATE cm\tframes\tms/frame\tpeak MB")
        for r in rows:
            ate = "-" if r["ate_m"] is None else f"{100 * r['ate_m']:.2f}"
            print(
                f"{Path(r['sequence']).name}\t{r['settings']}\t{ate}\t"
                f"{r['tracked']}/{r['frames']}\t{r['ms_per_frame'] or 0:.1f}\t"
                f"{r['peak_memory_mb']:.0f}" + (f"\t{r['error']}" if r["error"] else "")
            )
    return 1 if any(r["error"] for r in rows) else 0


if __name__ == "__main__":
    raise SystemExit(main())
