# The two commands of the README:
#   make demo   — fetch models once, then run the paper's example mission on the embedded default
#   make test   — fetch models and tools once, then run every test tier
.PHONY: demo test models tools

models:
	deploy/fetch-models.sh

tools:
	deploy/setup-tools.sh

demo: models
	cargo run --release -p vlnav-gateway --bin vlnav -- demo

test: models tools
	cargo test --workspace --no-fail-fast
