# The two commands of the README:
#   make demo   — fetch models once, then run the paper's example mission on the embedded default
#   make test   — install what the tests use (Debian packages, models, tools) once, then run every test tier
# and the checks CI runs before the tests:
#   make lint   — rustfmt and clippy, warnings as errors
.PHONY: demo test lint system models tools

system:
	deploy/setup-system.sh

models:
	deploy/fetch-models.sh

tools:
	deploy/setup-tools.sh

# The model converters build in the profile the demo runs in, so the demo
# compiles the workspace once.
demo: export VLNAV_CARGO_PROFILE = release
demo: models
	cargo run --release -p vlnav-gateway --bin vlnav -- demo

test: system models tools
	cargo test --workspace --no-fail-fast

lint:
	cargo fmt --all --check
	cargo clippy --workspace --all-targets -- -D warnings
