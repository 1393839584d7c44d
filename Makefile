# The two commands of the README:
#   make demo   — fetch models once, then run the paper's example mission on the embedded default
#   make test   — install what the tests use (Debian packages, models, tools, llama-server) once, then run every test tier
# and the checks CI runs before the tests:
#   make lint   — rustfmt and clippy, warnings as errors
# and the container images, built here with podman (no registry needed):
#   make images — vlnav:0.1.0 and vlnav-models:0.1.0 (deploy/README.md)
.PHONY: demo test lint system models tools llama-server images

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

# One build. The demo, the model converters (deploy/lib/workspace-bin.sh),
# the tests and the servers the tests start (tests/src/procs.rs) all build in
# the test profile (dev, whose dependencies are optimised) with the same
# features, so `make demo` then `make test` compile the workspace once. Cargo
# resolves features per command: a dependency's feature turned on by only one
# of them (a dev-dependency's, or the ROS 2 driver's) gives every crate above
# it a second build, so dev-dependencies add no features to crates the
# binaries use, and every build names FEATURES. The binaries have no unit
# tests (`test = false`) and the examples are left to clippy, so `make test`
# links only the test harnesses that hold tests.
FEATURES = vlnav-edge-agent/ros2

demo: export VLNAV_CARGO_PROFILE = dev
demo: models
	cargo run -p vlnav --features $(FEATURES) -- demo

# The release binaries built on this machine, stripped, and ./models, on a
# Debian base made with debootstrap once per machine (deploy/build-images.sh).
images: export VLNAV_CARGO_PROFILE = release
images: models
	cargo build --release --locked --features $(FEATURES) $(addprefix -p ,$(IMAGE_PACKAGES)) $(addprefix --bin ,$(IMAGE_BINARIES))
	deploy/build-images.sh --profile release

IMAGE_BINARIES = vlnav vlnav-gateway vlnav-ingress vlnav-planner vlnav-detector vlnav-reid vlnav-segmenter \
	vlnav-subgoal vlnav-local-planner vlnav-edge
IMAGE_PACKAGES = $(filter-out vlnav-edge,$(IMAGE_BINARIES)) vlnav-edge-agent

# The edge agent's ROS 2 driver is a cargo feature (it adds RustDDS to the
# build; edge/README.md); the tests build and run it. `--tests` runs every
# library's unit tests and every integration test; the doc tests follow.
test: system models tools llama-server
	cargo test --workspace --no-fail-fast --features $(FEATURES) --tests
	cargo test --workspace --no-fail-fast --features $(FEATURES) --doc

lint:
	cargo fmt --all --check
	cargo clippy --workspace --all-targets --features $(FEATURES) -- -D warnings
