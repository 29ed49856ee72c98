"""The binding's own share of a frame: per `track` call, the milliseconds spent outside the
pipeline (numpy checks and conversions in, the result's arrays out, the GIL) against the
pipeline's, measured inside the call (`Frame.timings`).

    python python/bench/binding_overhead.py SEQUENCE [--detector yolox|none] [--model M] [--json]
"""

import argparse
import json
import statistics

import stillpoint


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("sequence")
    p.add_argument("--detector", default="yolox", choices=["yolox", "none"])
    p.add_argument("--model")
    p.add_argument("--json", action="store_true")
    a = p.parse_args()
    src = stillpoint.open(a.sequence)
    frames = list(src)  # decoded before the clock: a file's decoding is not the binding's
    slam = stillpoint.Slam.for_source(src, detector=a.detector, model=a.model)
    binding, pipeline = [], []
    for f in frames:
        image = f.image if f.image is not None else f.gray
        t = slam.track(image, f.timestamp, depth=f.depth, right=f.right).timings
        binding.append(t["binding"])
        pipeline.append(t["total"] - t["binding"])
    slam.finish()
    out = {
        "sequence": src.name,
        "detector": a.detector,
        "frames": len(frames),
        "binding_ms_median": statistics.median(binding),
        "pipeline_ms_median": statistics.median(pipeline),
        "binding_share": sum(binding) / sum(pipeline),
    }
    if a.json:
        print(json.dumps(out))
    else:
        print(
            f"{out['sequence']} ({a.detector}, {out['frames']} frames): binding "
            f"{out['binding_ms_median']:.3f} ms, pipeline {out['pipeline_ms_median']:.2f} ms a "
            f"frame (medians); binding / pipeline {100 * out['binding_share']:.2f} %"
        )


if __name__ == "__main__":
    main()
