"""stillpoint.eval against evo on real trajectories (../shared/data/trajectories)."""

from __future__ import annotations

import numpy as np
import pytest

import stillpoint


def evo_ape(gt_path, est_path, align: bool, scale: bool) -> float:
    from evo.core import metrics, sync
    from evo.tools import file_interface

    gt = file_interface.read_tum_trajectory_file(str(gt_path))
    est = file_interface.read_tum_trajectory_file(str(est_path))
    gt, est = sync.associate_trajectories(gt, est, max_diff=0.01)
    if align or scale:
        est.align(gt, correct_scale=scale, correct_only_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((gt, est))
    return ape.get_statistic(metrics.StatisticsType.rmse)


def evo_rpe(gt_path, est_path) -> tuple[float, float]:
    from evo.core import metrics, sync
    from evo.tools import file_interface

    gt = file_interface.read_tum_trajectory_file(str(gt_path))
    est = file_interface.read_tum_trajectory_file(str(est_path))
    gt, est = sync.associate_trajectories(gt, est, max_diff=0.01)
    out = []
    for rel in (metrics.PoseRelation.translation_part, metrics.PoseRelation.rotation_angle_deg):
        rpe = metrics.RPE(rel, delta=1, delta_unit=metrics.Unit.frames, all_pairs=False)
        rpe.process_data((gt, est))
        out.append(rpe.get_statistic(metrics.StatisticsType.rmse))
    return out[0], out[1]


PAIRS = [
    ("rgbd_dataset_freiburg1_xyz_groundtruth.txt", "fr1_xyz_rgbdslam_estimate_evo.txt"),
    ("rgbd_dataset_freiburg2_desk_groundtruth.txt", "fr2_desk_ORB_estimate_evo.txt"),
]


@pytest.mark.parametrize("gt,est", PAIRS)
def test_ate_and_rpe_equal_evos(shared, gt, est):
    d = shared / "data" / "trajectories" / "tum"
    for align, (a, s) in {"none": (False, False), "se3": (True, False), "sim3": (True, True)}.items():
        ours = stillpoint.eval.ate(d / gt, d / est, align=align)["rmse"]
        assert ours == pytest.approx(evo_ape(d / gt, d / est, a, s), rel=1e-9, abs=1e-12), align
    t, r = evo_rpe(d / gt, d / est)
    ours = stillpoint.eval.rpe(d / gt, d / est)
    assert ours["translation"]["rmse"] == pytest.approx(t, rel=1e-9)
    assert ours["rotation_deg"]["rmse"] == pytest.approx(r, rel=1e-9)


def test_arrays_and_files_give_the_same_numbers(shared):
    d = shared / "data" / "trajectories" / "tum"
    gt, est = d / PAIRS[0][0], d / PAIRS[0][1]
    rows = np.loadtxt(est, ndmin=2)
    assert stillpoint.eval.ate(gt, rows)["rmse"] == stillpoint.eval.ate(gt, est)["rmse"]
