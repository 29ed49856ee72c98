"""Notebook-style: run a sequence, then plot the trajectory against the ground truth and one
frame's keypoints, kept (green) and culled as moving (red), with the objects' boxes.

    python plot_run.py SEQUENCE_FOLDER [OUT.png]
"""
import sys

import matplotlib

matplotlib.use("Agg")  # no display needed; in a notebook leave this out
import matplotlib.pyplot as plt
import numpy as np

import stillpoint

# %% Track every frame, keep the one with the most culled keypoints.
seq = stillpoint.open(sys.argv[1])
slam = stillpoint.Slam.for_source(seq)
busiest, busiest_image = None, None
for frame in seq:
    result = slam.track_frame(frame)
    if busiest is None or result.dynamic.sum() > busiest.dynamic.sum():
        busiest, busiest_image = result, frame.image
run = slam.finish()

# %% The trajectory seen from above, after aligning it to the ground truth.
gt = np.loadtxt(seq.ground_truth, ndmin=2)
est = run.trajectory
ate = stillpoint.eval.ate(seq.ground_truth, est, align="se3")
fig, (top, image) = plt.subplots(1, 2, figsize=(13, 5))
top.plot(gt[:, 1], gt[:, 3], "k--", label="ground truth")
top.plot(est[:, 1], est[:, 3], "b-", label=f"stillpoint (ATE {100 * ate['rmse']:.2f} cm)")
top.set_xlabel("x (m)")
top.set_ylabel("z (m)")
top.set_aspect("equal")
top.legend()

# %% One frame: kept keypoints green, culled ones red, boxes by state.
image.imshow(busiest_image)
kept, culled = busiest.keypoints[~busiest.dynamic], busiest.keypoints[busiest.dynamic]
image.scatter(kept[:, 0], kept[:, 1], s=4, c="lime", label=f"kept {len(kept)}")
image.scatter(culled[:, 0], culled[:, 1], s=4, c="red", label=f"culled {len(culled)}")
for b in busiest.boxes:
    colour = {"moving": "red", "carried": "orange"}.get(b["state"], "lime")
    image.add_patch(plt.Rectangle((b["x1"], b["y1"]), b["x2"] - b["x1"], b["y2"] - b["y1"],
                                  fill=False, color=colour))
    image.text(b["x1"], b["y1"] - 3, f"{b['class']} {b['state']}", color=colour, fontsize=8)
image.set_title(f"frame {busiest.index}")
image.legend(loc="lower right")
image.axis("off")
fig.tight_layout()
fig.savefig(sys.argv[2] if len(sys.argv) > 2 else "run.png", dpi=90)
