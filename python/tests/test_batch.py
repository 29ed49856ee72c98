"""python -m stillpoint.batch on Ray (local, and a `ray start --head` through --address) and on
a local process pool: one row per sequence x setting, equal to single runs."""

from __future__ import annotations

import csv
import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

import stillpoint
from stillpoint import batch

SETTING = "orb.n_features"
VALUES = ["600", "1000"]


@pytest.fixture(scope="module")
def two_sequences(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("batch")
    out = []
    for preset, seed in (("walking_xyz", 4), ("walking_halfsphere", 5)):
        stillpoint.synth(preset, root / preset, seed=seed, frames=30)
        out.append(root / preset)
    return out


def single_run_ate(seq: Path, value: str) -> float:
    src = stillpoint.open(seq)
    slam = stillpoint.Slam.for_source(src, detector="none", settings={SETTING: value, "detect.threads": "1"})
    for fr in src:
        slam.track_frame(fr)
    run = slam.finish()
    return stillpoint.eval.ate(str(src.ground_truth), run.trajectory)["rmse"]


def run_batch(seqs, out: Path, *extra: str) -> list[dict]:
    cmd = [sys.executable, "-m", "stillpoint.batch", "--sequences", *map(str, seqs),
           "--set", f"{SETTING}={','.join(VALUES)}", "--detector", "none", "--out", str(out),
           "--json", *extra]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    rows = json.loads(done.stdout)
    assert (out / "runs.csv").is_file() and (out / "runs.parquet").is_file()
    with open(out / "runs.csv") as f:
        assert len(list(csv.DictReader(f))) == len(rows)
    return rows


def check_rows(rows, seqs):
    assert len(rows) == 4
    assert {(Path(r["sequence"]).name, json.loads(r["settings"])[SETTING]) for r in rows} == {
        (s.name, v) for s in seqs for v in VALUES
    }
    for r in rows:
        assert r["error"] is None and r["tracked"] == r["frames"] == 30
        assert r["peak_memory_mb"] > 0 and Path(r["trajectory"]).is_file()
        value = json.loads(r["settings"])[SETTING]
        assert r["ate_m"] == single_run_ate(Path(r["sequence"]), value)


def test_ray_with_two_local_workers(two_sequences, tmp_path):
    rows = run_batch(two_sequences, tmp_path / "out", "--engine", "ray", "--workers", "2")
    check_rows(rows, two_sequences)


def test_a_local_process_pool(two_sequences, tmp_path):
    rows = run_batch(two_sequences, tmp_path / "out", "--engine", "local", "--workers", "2")
    check_rows(rows, two_sequences)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_ray_through_an_address(two_sequences, tmp_path):
    """A `ray start --head` on the machine, reached through --address (the cluster's GCS
    address; `ray://host:10001` goes through Ray's client server, which on this machine failed
    to start its per-client process now and then: docs/python.md)."""
    ray = shutil.which("ray", path=os.path.dirname(sys.executable)) or shutil.which("ray")
    assert ray, "the ray command comes with stillpoint-slam[batch]"
    gcs = free_port()
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0")
    subprocess.run([ray, "start", "--head", f"--port={gcs}", "--num-cpus=2",
                    "--include-dashboard=false", "--disable-usage-stats"],
                   check=True, env=env, capture_output=True)
    try:
        rows = run_batch(two_sequences, tmp_path / "out", "--engine", "ray",
                         "--address", f"127.0.0.1:{gcs}")
    finally:
        subprocess.run([ray, "stop", "--force"], env=env, capture_output=True)
    check_rows(rows, two_sequences)


def test_set_values_split_on_commas_outside_brackets():
    assert batch.parse_set("a.b=1,2") == ("a.b", ["1", "2"])
    assert batch.parse_set("a.b=[1,2],[3]") == ("a.b", ["[1,2]", "[3]"])
    assert batch.grid([("a", ["1", "2"]), ("b", ["x"])]) == [{"a": "1", "b": "x"}, {"a": "2", "b": "x"}]
