#!/usr/bin/env bash
# Fetch ONNX Runtime's shared library for stillpoint's `ort` backend (the `ort` crate is built
# with `load-dynamic`, so the library is loaded at run time and nothing is downloaded at build time).
#
# It takes libonnxruntime.so from the PyPI `onnxruntime` wheel (pip download, no install),
# puts it in third_party/onnxruntime/ (gitignored) with a libonnxruntime.so link, and prints the
# ORT_DYLIB_PATH to export. Usage: scripts/setup-onnxruntime.sh [VERSION]   (default: latest)
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dest="$root/third_party/onnxruntime"
spec="onnxruntime${1:+==$1}"

pip=""
for candidate in "python3 -m pip" "pip3" "pip"; do
    if $candidate --version >/dev/null 2>&1; then pip="$candidate"; break; fi
done
[ -n "$pip" ] || { echo "error: pip not found (needed to download the onnxruntime wheel)" >&2; exit 1; }

tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
echo "downloading $spec wheel with $pip ..." >&2
$pip download --quiet --no-deps --only-binary=:all: --dest "$tmp" "$spec" >&2
wheel="$(ls "$tmp"/onnxruntime-*.whl 2>/dev/null | head -n1)"
[ -n "$wheel" ] || { echo "error: no onnxruntime wheel in $tmp" >&2; exit 1; }

mkdir -p "$dest"
python3 - "$wheel" "$dest" <<'PY'
import re, sys, zipfile, os
wheel, dest = sys.argv[1], sys.argv[2]
with zipfile.ZipFile(wheel) as z:
    libs = [n for n in z.namelist() if re.match(r"onnxruntime/capi/libonnxruntime\.so\.\d", n)]
    if not libs:
        sys.exit(f"error: {wheel} holds no onnxruntime/capi/libonnxruntime.so.*")
    for name in libs:
        out = os.path.join(dest, os.path.basename(name))
        with z.open(name) as src, open(out, "wb") as dst:
            dst.write(src.read())
        print(out, file=sys.stderr)
PY
lib="$(ls "$dest"/libonnxruntime.so.* | sort -V | tail -n1)"
ln -sf "$(basename "$lib")" "$dest/libonnxruntime.so"
echo "installed $lib" >&2
echo "export ORT_DYLIB_PATH=$dest/libonnxruntime.so"
