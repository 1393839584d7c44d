# Sourced by model fragments: `workspace_bin NAME` builds the workspace's
# binaries in $VLNAV_CARGO_PROFILE (default dev) with the features `make demo`
# and `make test` build with, and prints the path of the binary NAME. Built
# any other way (`cargo run -p vlnav-detector`, say) the converters would
# resolve their dependencies' features differently, and the demo and the
# tests would compile most of the workspace a second time (Makefile,
# "One build").
VLNAV_CARGO_FEATURES=${VLNAV_CARGO_FEATURES:-vlnav-edge-agent/ros2}
workspace_bin() {
  local name=$1 profile=${VLNAV_CARGO_PROFILE:-dev} dir
  echo "building the workspace's binaries ($profile, features $VLNAV_CARGO_FEATURES) for $name" >&2
  (cd "$root" && cargo build --profile "$profile" --workspace --bins --features "$VLNAV_CARGO_FEATURES") >&2 \
    || return 1
  dir=${CARGO_TARGET_DIR:-target}
  case $dir in /*) ;; *) dir=$root/$dir ;; esac
  case $profile in
    dev | test) dir=$dir/debug ;;
    bench) dir=$dir/release ;;
    *) dir=$dir/$profile ;;
  esac
  echo "$dir/$name"
}
