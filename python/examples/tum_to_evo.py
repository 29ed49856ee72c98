"""A TUM RGB-D folder in, a TUM trajectory file out, scored by evo."""
import subprocess
import sys

import stillpoint

seq = stillpoint.open(sys.argv[1])  # rgb.txt, depth.txt, groundtruth.txt
slam = stillpoint.Slam.for_source(seq)  # YOLOX-nano and the dynamic front-end
for frame in seq:
    slam.track_frame(frame)
run = slam.finish()
run.save_trajectory("trajectory.txt")
print(stillpoint.eval.ate(seq.ground_truth, run.trajectory, align="se3"))  # evo's numbers
subprocess.run(["evo_ape", "tum", seq.ground_truth, "trajectory.txt", "-a"], check=True)
