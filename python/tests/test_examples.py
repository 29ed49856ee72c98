"""The README's Python examples run as written."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
README = Path(__file__).resolve().parents[2] / "README.md"


def run_example(name, args, cwd, shared):
    env = dict(os.environ, STILLPOINT_MODELS=str(shared / "models"))
    # evo_ape is beside the interpreter in a virtual environment.
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env.get("PATH", "")
    return subprocess.run([sys.executable, str(EXAMPLES / name), *map(str, args)], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=900)


def test_the_readme_shows_the_tum_example_as_it_is():
    assert (EXAMPLES / "tum_to_evo.py").read_text().strip() in README.read_text()


def test_tum_to_evo(shared, walking, tmp_path):
    done = run_example("tum_to_evo.py", [walking], tmp_path, shared)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "trajectory.txt").is_file()
    assert "'rmse'" in done.stdout and "rmse" in done.stdout.split("'rmse'")[1]


def test_plot_run(shared, walking, tmp_path):
    done = run_example("plot_run.py", [walking, tmp_path / "run.png"], tmp_path, shared)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "run.png").stat().st_size > 10_000
