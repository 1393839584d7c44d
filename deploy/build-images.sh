#!/usr/bin/env bash
# Builds the container images here, with podman, from binaries built on this
# machine and the models in ./models, on a Debian base made locally with
# debootstrap (no container registry needed):
#
#   vlnav:<tag>         every vlnav binary (deploy/Containerfile)
#   vlnav-models:<tag>  the models deploy/fetch-models.sh fetched (deploy/Containerfile.models)
#
# The base, localhost/vlnav-base:bookworm, is made once per machine
# (`debootstrap --variant=minbase bookworm` from the Debian mirror apt uses,
# trimmed, then `podman import`) and kept in podman's image store.
#
# Usage: deploy/build-images.sh [--profile release|debug|<profile>] [--bin-dir DIR]
#                               [--tag TAG] [--base-only] [--rebuild-base]
#   --profile  which cargo profile's binaries to copy in (default release:
#              target/release; `make images` builds them first)
#   --bin-dir  take the binaries from DIR instead
#   --tag      image tag (default 0.1.0, the tag k8s/ uses)
# Environment: VLNAV_DEBIAN_MIRROR (default: apt's bookworm source),
# VLNAV_BASE_IMAGE (an image to build on instead of the local base; it needs
# `cp` for the models init container, e.g. docker.io/library/debian:bookworm-slim),
# VLNAV_MODELS_DIR (default ./models), CONTAINERS_CONF (default deploy/containers.conf).
# Binaries are stripped on the way in. They must be linked against glibc no
# newer than bookworm's (2.36): build them on bookworm (or older), or use the
# multi-stage deploy/Dockerfile where a registry is reachable.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
export CONTAINERS_CONF=${CONTAINERS_CONF:-$root/deploy/containers.conf}

BINARIES=(vlnav vlnav-gateway vlnav-ingress vlnav-planner vlnav-detector vlnav-reid vlnav-segmenter
  vlnav-subgoal vlnav-local-planner vlnav-edge)
BASE_TAG=localhost/vlnav-base:bookworm

profile=release
bin_dir=
tag=0.1.0
base_only=false
rebuild_base=false
while [ $# -gt 0 ]; do
  case "$1" in
    --profile) profile=$2; shift 2 ;;
    --bin-dir) bin_dir=$2; shift 2 ;;
    --tag) tag=$2; shift 2 ;;
    --base-only) base_only=true; shift ;;
    --rebuild-base) rebuild_base=true; shift ;;
    -h | --help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
    *) echo "unknown argument: $1 (see --help)" >&2; exit 2 ;;
  esac
done

if ! command -v podman >/dev/null; then
  echo "podman is not installed: sudo apt-get install -y --no-install-recommends podman runc buildah debootstrap" >&2
  echo "(the list is .ci/apt/containers.txt; deploy/setup-system.sh installs it)" >&2
  exit 1
fi
if [ "$(id -u)" -ne 0 ]; then
  echo "run as root: the images are built and run with rootful podman (debootstrap needs root too)" >&2
  exit 1
fi

say() { printf '== images: %s\n' "$*"; }

# The Debian mirror apt already uses for bookworm.
debian_mirror() {
  if [ -n "${VLNAV_DEBIAN_MIRROR:-}" ]; then
    echo "$VLNAV_DEBIAN_MIRROR"
    return
  fi
  local m
  # shellcheck disable=SC2016 # apt's own $(FIELD) placeholders
  m=$(apt-get indextargets --format '$(RELEASE) $(REPO_URI)' 2>/dev/null | awk '$1 == "bookworm" { print $2; exit }')
  echo "${m:-http://deb.debian.org/debian/}"
}

# localhost/vlnav-base:bookworm: minimal Debian (glibc, libstdc++, coreutils
# for the models init container's `cp`, CA certificates), a `nonroot` user
# with uid/gid 65532 as in distroless, no apt caches, documentation or locales.
make_base() {
  if ! $rebuild_base && podman image exists "$BASE_TAG"; then
    say "base $BASE_TAG present (made $(podman image inspect --format '{{.Created}}' "$BASE_TAG" | cut -c1-19))"
    return
  fi
  command -v debootstrap >/dev/null || { echo "debootstrap is not installed: sudo apt-get install -y debootstrap" >&2; exit 1; }
  local mirror rootfs started
  mirror=$(debian_mirror)
  started=$(date +%s)
  rootfs=$(mktemp -d /var/tmp/vlnav-base.XXXXXX)
  # --one-file-system: never into a /proc, /sys or /dev that a failed
  # debootstrap left mounted inside.
  # shellcheck disable=SC2064
  trap "rm -rf --one-file-system '$rootfs'" EXIT
  say "making the base with debootstrap --variant=minbase bookworm from $mirror (once per machine)"
  debootstrap --variant=minbase --include=ca-certificates bookworm "$rootfs" "$mirror" >"$rootfs.log" 2>&1 || {
    tail -n 30 "$rootfs.log" >&2
    exit 1
  }
  rm -f "$rootfs.log"
  if grep -q " $rootfs/" /proc/mounts; then
    echo "debootstrap left file systems mounted under $rootfs; unmount them and run again" >&2
    exit 1
  fi
  # Nothing of the bootstrap's caches, documentation, locales or device nodes
  # (the runtime provides /dev).
  rm -rf --one-file-system "${rootfs:?}"/var/cache/apt/archives/*.deb "${rootfs:?}"/var/cache/apt/*.bin "${rootfs:?}"/var/lib/apt/lists/* \
    "${rootfs:?}"/var/log/* "${rootfs:?}"/usr/share/doc/* "${rootfs:?}"/usr/share/man/* "${rootfs:?}"/usr/share/info/* \
    "${rootfs:?}"/usr/share/locale/* "${rootfs:?}"/usr/share/lintian "${rootfs:?}"/dev/* "${rootfs:?}"/run/* "${rootfs:?}"/tmp/* \
    "${rootfs:?}"/var/tmp/*
  echo "nonroot:x:65532:65532:nonroot:/home/nonroot:/usr/sbin/nologin" >>"$rootfs/etc/passwd"
  echo "nonroot:x:65532:" >>"$rootfs/etc/group"
  echo "nonroot:*:19000:0:99999:7:::" >>"$rootfs/etc/shadow"
  install -d -o 65532 -g 65532 -m 0750 "$rootfs/home/nonroot"
  tar --numeric-owner --xattrs -C "$rootfs" -c . |
    podman import --quiet \
      --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
      --change 'ENV SSL_CERT_FILE=/etc/ssl/certs/ca-certificates.crt' \
      --change 'LABEL org.opencontainers.image.description="Debian bookworm minbase for vlnav (debootstrap)"' \
      --change "LABEL io.vlnav.debian-mirror=$mirror" \
      --change 'USER 65532:65532' \
      --change 'CMD ["/bin/sh"]' \
      --message "debootstrap --variant=minbase bookworm $mirror" \
      - "$BASE_TAG" >/dev/null
  rm -rf --one-file-system "$rootfs"
  trap - EXIT
  say "base $BASE_TAG made in $(($(date +%s) - started)) s, $(size_of "$BASE_TAG")"
}

size_of() {
  podman image inspect --format '{{.Size}}' "$1" | awk '{ printf "%.1f MB", $1 / 1e6 }'
}

# After a build: k8s/ names the images `vlnav:<tag>`, which containerd (k3s)
# reads as docker.io/library/vlnav:<tag>, so that name too makes `podman save`
# archives that k3s imports under the name the pods ask for (deploy/README.md).
# The image the tag named before, now untagged, goes unless a container uses it.
tagged() {
  local name=$1 previous=$2
  podman tag "$name:$tag" "docker.io/library/$name:$tag"
  if [ -n "$previous" ] && [ "$previous" != "$(podman image inspect --format '{{.Id}}' "$name:$tag")" ]; then
    podman rmi "$previous" >/dev/null 2>&1 || true
  fi
}

make_base
$base_only && exit 0
base=${VLNAV_BASE_IMAGE:-$BASE_TAG}

# ---- vlnav:<tag>: the binaries, stripped ---------------------------------------
if [ -z "$bin_dir" ]; then
  target=${CARGO_TARGET_DIR:-$root/target}
  case "$profile" in
    dev) bin_dir=$target/debug ;;
    *) bin_dir=$target/$profile ;;
  esac
fi
missing=()
for b in "${BINARIES[@]}"; do [ -x "$bin_dir/$b" ] || missing+=("$b"); done
if [ ${#missing[@]} -gt 0 ]; then
  echo "missing in $bin_dir: ${missing[*]}" >&2
  flag=--release
  [ "$profile" = release ] || flag="--profile $profile"
  [ "$profile" = debug ] && flag=
  pkgs=$(printf ' -p %s' vlnav vlnav-gateway vlnav-ingress vlnav-planner vlnav-detector vlnav-reid \
    vlnav-segmenter vlnav-subgoal vlnav-local-planner vlnav-edge-agent)
  echo "build them first: cargo build $flag$pkgs --bins (or: make images)" >&2
  exit 1
fi
ctx="${CARGO_TARGET_DIR:-$root/target}/images/$tag/context"
rm -rf "$ctx"
mkdir -p "$ctx/bin"
for b in "${BINARIES[@]}"; do
  strip --strip-all -o "$ctx/bin/$b" "$bin_dir/$b"
done
say "vlnav:$tag from $bin_dir (stripped: $(du -sh "$ctx/bin" | cut -f1)) on $base"
previous=$(podman image inspect --format '{{.Id}}' "vlnav:$tag" 2>/dev/null || true)
podman build --quiet --pull=never --build-arg "BASE_IMAGE=$base" \
  --label "io.vlnav.binaries=$bin_dir" -f "$root/deploy/Containerfile" -t "vlnav:$tag" "$ctx" >/dev/null
rm -rf "$ctx"
tagged vlnav "$previous"

# ---- vlnav-models:<tag>: ./models as fetch-models.sh leaves it -------------------
models=${VLNAV_MODELS_DIR:-$root/models}
[ -d "$models/minilm" ] || { echo "no models in $models: run deploy/fetch-models.sh (or make models) first" >&2; exit 1; }
# The same content makes the same image: skip the copy when nothing changed.
# Left out: hidden entries (the fetch script's Python environment) and
# llama.cpp/ (llama-server, built by deploy/llama-server.sh for a test, not a model).
ignore="$root/deploy/Containerfile.models.containerignore"
listing=$(cd "$models" && find . -mindepth 1 \( -path './.*' -o -path ./llama.cpp \) -prune -o -type f -printf '%P %s %T@\n' |
  LC_ALL=C sort)
stamp=$(sha256sum <<<"$listing" | cut -c1-16)
current=$(podman image inspect --format '{{index .Labels "io.vlnav.models-stamp"}}' "vlnav-models:$tag" 2>/dev/null || true)
current_base=$(podman image inspect --format '{{index .Labels "io.vlnav.base"}}' "vlnav-models:$tag" 2>/dev/null || true)
if [ "$current" = "$stamp" ] && [ "$current_base" = "$(podman image inspect --format '{{.Id}}' "$base")" ]; then
  say "vlnav-models:$tag is up to date with $models"
else
  say "vlnav-models:$tag from $models ($(awk '{ s += $2 } END { printf "%.0f MB", s / 1e6 }' <<<"$listing"))"
  previous=$(podman image inspect --format '{{.Id}}' "vlnav-models:$tag" 2>/dev/null || true)
  podman build --quiet --pull=never --build-arg "BASE_IMAGE=$base" --ignorefile "$ignore" \
    --label "io.vlnav.models-stamp=$stamp" --label "io.vlnav.base=$(podman image inspect --format '{{.Id}}' "$base")" \
    -f "$root/deploy/Containerfile.models" -t "vlnav-models:$tag" "$models" >/dev/null
  tagged vlnav-models "$previous"
fi

# ---- smoke: each image starts as its non-root user on a read-only root --------------
user=$(podman image inspect --format '{{.Config.User}}' "vlnav:$tag")
[ "$user" = "65532:65532" ] || { echo "vlnav:$tag runs as '$user', not 65532:65532" >&2; exit 1; }
podman run --rm --read-only --network none "vlnav:$tag" --help >/dev/null
podman run --rm --read-only --network none --entrypoint vlnav-gateway "vlnav:$tag" --help >/dev/null
uid=$(podman run --rm --read-only --network none "vlnav-models:$tag" id -u)
[ "$uid" = 65532 ] || { echo "vlnav-models:$tag runs as uid $uid" >&2; exit 1; }
podman run --rm --read-only --network none "vlnav-models:$tag" test -s /models/minilm/model.safetensors

say "built (sizes as podman counts them; both share the base's layer):"
for i in "$BASE_TAG" "vlnav:$tag" "vlnav-models:$tag"; do
  printf '   %-34s %s\n' "$i" "$(size_of "$i")"
done
