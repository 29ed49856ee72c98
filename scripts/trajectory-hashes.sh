#!/usr/bin/env bash
# The README tables' runs, seed 0, gt boxes and YOLOX (tract), run `--sequential`, and the SHA-256
# of each trajectory: a change that must not move results (a refactor) keeps every line of
# scripts/trajectory-hashes.txt. Needs ../shared (textures, model) and a release build with
# `--features tract`. Best compared on the machine that recorded them (or record the base
# first): tract picks its kernels by the CPU's vector extensions, so a YOLOX box may differ in
# its last bits between machines. living_close_mono_s0_yolox was recorded anew on an AVX2-only
# EPYC where it differed (ATE the same to 0.01 cm), which of machine or code not pinned.
#   scripts/trajectory-hashes.sh          # compare with scripts/trajectory-hashes.txt
#   scripts/trajectory-hashes.sh --write  # record them anew (after a change meant to move them)
set -euo pipefail
cd "$(dirname "$0")/.."
shared="${STILLPOINT_SHARED:-../shared}"
bin=target/release/stillpoint
out="${TMPDIR:-/tmp}/stillpoint-hashes"
mkdir -p "$out"
common=(--log warn --seeds 0 --modes gt,yolox --set slam.local_mapping_thread=false --out "$out"
  --textures "$shared/data/tum/fr3_walking_xyz_first_frame"
  --model "$shared/models/yolox_nano_480x640.onnx")
"$bin" bench matrix --presets living_cross,living_close,living_turn,living_empty "${common[@]}" >/dev/null
"$bin" bench matrix --presets living_cross,living_close,living_turn,living_empty,street --monocular "${common[@]}" >/dev/null
now=$(cd "$out" && sha256sum ./*_s0_gt.txt ./*_s0_yolox.txt | sed 's# \./# #' | sort -k2)
if [ "${1:-}" = "--write" ]; then
  echo "$now" > scripts/trajectory-hashes.txt
  echo "recorded $(echo "$now" | wc -l) trajectories"
elif diff <(echo "$now") scripts/trajectory-hashes.txt; then
  echo "all $(echo "$now" | wc -l) trajectories byte for byte the same"
else
  echo "trajectories changed (above: < now, > recorded)" >&2
  exit 1
fi
