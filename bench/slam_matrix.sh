#!/usr/bin/env bash
# Synthetic accuracy matrix: presets x seeds, SLAM with the dynamic front-end off, on with
# ground-truth boxes, and on with YOLOX; one JSON summary per run, then a table of ATE RMSE.
#
# usage: bench/slam_matrix.sh BIN OUT_DIR [JOBS]
#   env PRESETS (default: the TUM-like seven), SEEDS (default "0 1 2"), FRAMES (300),
#       MODEL (YOLOX ONNX; default ../shared/models/yolox_nano_480x640.onnx), NOISE (none|kinect)
# Runs are independent and single-threaded (--sequential), so JOBS in parallel is safe.
set -euo pipefail
BIN=$(realpath "$1"); OUT=$2; JOBS=${3:-$(nproc)}
PRESETS=${PRESETS:-"static walking_xyz walking_static walking_rpy walking_halfsphere sitting_xyz sitting_halfsphere"}
SEEDS=${SEEDS:-"0 1 2"}
FRAMES=${FRAMES:-300}
NOISE=${NOISE:-none}
MODEL=${MODEL:-$(dirname "$0")/../../shared/models/yolox_nano_480x640.onnx}
mkdir -p "$OUT/seq" "$OUT/runs"
export BIN OUT FRAMES NOISE MODEL

synth_one() { # preset seed
  local d="$OUT/seq/$1_s$2"
  [ -f "$d/groundtruth.txt" ] || "$BIN" synth --preset "$1" --seed "$2" --frames "$FRAMES" \
    --noise "$NOISE" --out "$d" --log warn > /dev/null
}
run_one() { # preset seed mode
  local d="$OUT/seq/$1_s$2" r="$OUT/runs/$1_s$2_$3"
  case $3 in
    off) set -- --no-dynamic --detector none ;;
    gt) set -- --detector gt ;;
    yolox) set -- --detector yolox --model "$MODEL" ;;
  esac
  "$BIN" run --dataset "$d" --sequential --json --out "$r.txt" --log warn "$@" > "$r.json" 2> "$r.err" \
    || echo "{\"error\": \"exit $?\"}" > "$r.json"
}
export -f synth_one run_one

for p in $PRESETS; do for s in $SEEDS; do echo "$p $s"; done; done \
  | xargs -P "$JOBS" -L 1 bash -c 'synth_one $0 $1'
for p in $PRESETS; do for s in $SEEDS; do for m in off gt yolox; do echo "$p $s $m"; done; done; done \
  | xargs -P "$JOBS" -L 1 bash -c 'run_one $0 $1 $2'

python3 - "$OUT" <<'PY'
import json, pathlib, sys, collections
out = pathlib.Path(sys.argv[1])
cells = collections.defaultdict(list)
for f in sorted((out / "runs").glob("*.json")):
    preset_seed, mode = f.stem.rsplit("_", 1)
    preset = preset_seed.rsplit("_s", 1)[0]
    try:
        d = json.loads(f.read_text())
        v = d["ate"]["rmse"] * 100 if d.get("ate") else float("nan")
    except (ValueError, KeyError, TypeError):
        v = float("nan")
    cells[(preset, mode)].append(v)
presets = sorted({p for p, _ in cells})
print("| sequence | off (cm) | on, gt boxes (cm) | on, YOLOX (cm) |")
print("|---|---|---|---|")
for p in presets:
    row = []
    for m in ("off", "gt", "yolox"):
        v = cells.get((p, m), [])
        row.append(" / ".join(f"{x:.2f}" for x in v) if v else "-")
    print(f"| {p} | " + " | ".join(row) + " |")
print("\n(one number per seed)")
PY
