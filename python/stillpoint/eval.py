"""Trajectory metrics with evo's numbers (evo_ape / evo_rpe, tum or kitti).

`gt` and `est` are a trajectory file's path (format "tum", "kitti" or "euroc") or an (N, 8)
float64 array of TUM rows (t tx ty tz qx qy qz qw), such as `Run.trajectory`.

>>> stillpoint.eval.ate("groundtruth.txt", run.trajectory, align="se3")["rmse"]   # metres
"""

from ._stillpoint import ate, rpe

__all__ = ["ate", "rpe"]
