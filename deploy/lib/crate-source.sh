# Sourced by model fragments: `crate_source NAME VERSION` prints the directory
# of that crate's published sources, fetched with cargo from crates.io into
# the local registry cache ($VLNAV_MODELS_DIR/.cargo-fetch holds the
# throwaway project that asks for it).
crate_source() {
  local name=$1 version=$2 proj="$VLNAV_MODELS_DIR/.cargo-fetch/$1" d
  mkdir -p "$proj/src"
  cat >"$proj/Cargo.toml" <<TOML
[package]
name = "vlnav-fetch-$name"
version = "0.0.0"
edition = "2021"
publish = false

[workspace]

[dependencies]
$name = "=$version"
TOML
  echo 'fn main() {}' >"$proj/src/main.rs"
  (cd "$proj" && cargo fetch --quiet) || return 1
  for d in "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/"$name-$version"; do
    [ -d "$d" ] && { echo "$d"; return 0; }
  done
  echo "$name $version sources not found under ${CARGO_HOME:-$HOME/.cargo}/registry/src" >&2
  return 1
}
