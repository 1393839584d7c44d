#!/usr/bin/env bash
# The stack as separate containers on one podman network, wired the way
# k8s/base wires it, for a machine without Kubernetes:
#
#   deploy/run-containers.sh up            start (or start again) every container
#   deploy/run-containers.sh down          remove the containers, network and volumes
#   deploy/run-containers.sh status        list them
#   deploy/run-containers.sh kill SERVICE  SIGKILL one (e.g. local-planner)
#   deploy/run-containers.sh start SERVICE start it again and wait until it is healthy
#
# One container per Deployment of k8s/base (gateway, ingress, planner,
# detector, reid, segmenter, subgoal, local-planner) from vlnav:<tag>, plus an
# edge agent driving the simulated Husky. Each container gets the
# environment its Deployment gets: vlnav-config's data (read from
# k8s/base/configmap.yaml) and the Deployment's own `env:` (read from
# k8s/base/<service>.yaml), its component's certificate at /etc/vlnav/tls
# (from `vlnav credentials k8s`, run in the image), uid 65532, a read-only
# root with a 64 MiB /tmp, every capability dropped, no new privileges. The
# model-using services (ingress, planner, detector, reid) read /models from a
# volume that a vlnav-models container filled first with the init
# container's `cp -a /models/. /mnt/models/`. The Services' names (detector,
# detector-replicas, ...) resolve to each container's fixed address on the
# network. The gateway's port is published on the host; health answers in
# plaintext on each container's port 8090, as the probes ask it.
#
# Not carried over: the OpenTelemetry Collector and Jaeger (images from a
# registry; the OTEL_EXPORTER_* settings are left out, so nothing exports
# spans), resource limits, HPAs and restarts of a container that dies.
#
# Environment (defaults in brackets):
#   VLNAV_PROJECT [vlnav]          prefix of container, network and volume names
#   VLNAV_TAG [0.1.0]              tag of vlnav and vlnav-models (deploy/build-images.sh)
#   VLNAV_GATEWAY_PORT [50051]     host port the gateway is published on
#   VLNAV_GATEWAY_ADDRESS [127.0.0.1]  host address it is published on
#   VLNAV_GATEWAY_NAMES []         more names the gateway's certificate carries (comma-separated)
#   VLNAV_SUBNET [10.89.77]        the network's /24 (first three octets)
#   VLNAV_CREDENTIALS [.vlnav/containers/<project>]  certificates and tokens (kept by `down`)
#   VLNAV_PERCEPTION [realistic]   realistic | oracle | neural: the perception
#                                  stages' backends, as `vlnav up --perception`
#                                  (neural is the manifests' own: NanoDet,
#                                  MobileNetV2, colour segmenter, slow on CPU)
#   VLNAV_ROBOT_ID [husky-1]       the simulated robot; VLNAV_EDGE_* variables
#                                  set here go to its edge agent (scenario, size, ...)
#   RUST_LOG [info]
# Needs rootful podman (run as root) and grpcurl (deploy/setup-tools.sh puts
# it in .venv/bin) for the health checks.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
export CONTAINERS_CONF=${CONTAINERS_CONF:-$root/deploy/containers.conf}

project=${VLNAV_PROJECT:-vlnav}
tag=${VLNAV_TAG:-0.1.0}
image=vlnav:$tag
models_image=vlnav-models:$tag
gw_port=${VLNAV_GATEWAY_PORT:-50051}
gw_address=${VLNAV_GATEWAY_ADDRESS:-127.0.0.1}
subnet=${VLNAV_SUBNET:-10.89.77}
creds=${VLNAV_CREDENTIALS:-$root/.vlnav/containers/$project}
perception=${VLNAV_PERCEPTION:-realistic}
robot=${VLNAV_ROBOT_ID:-husky-1}
network=$project
label=io.vlnav.project=$project

# The Deployments (ports and environment come from their manifests), each
# one's address on the network, and the Services that name it.
SERVICES=(ingress planner detector reid segmenter subgoal local-planner gateway)
declare -A HOST=([gateway]=10 [ingress]=11 [planner]=12 [detector]=13 [reid]=14 [segmenter]=15
  [subgoal]=16 [local-planner]=17 [edge]=20)
declare -A NAMES=([gateway]="gateway" [ingress]="ingress ingress-replicas" [planner]="planner planner-replicas"
  [detector]="detector detector-replicas" [reid]="reid" [segmenter]="segmenter segmenter-replicas"
  [subgoal]="subgoal" [local-planner]="local-planner")
# The services whose pods have the `models` init container.
declare -A MODELS=([ingress]=1 [planner]=1 [detector]=1 [reid]=1)

say() { printf '== containers: %s\n' "$*"; }
die() { printf 'run-containers: %s\n' "$*" >&2; exit 1; }
ip_of() { echo "$subnet.${HOST[$1]}"; }
# A fixed, locally administered MAC from the address: a container started
# again keeps its address and its MAC, as a restarted container keeps its
# pod's network. (A new MAC on the same address leaves its peers' ARP
# entries stale, and their connections to it hang for ~20 s.)
mac_of() { local a b c d; IFS=. read -r a b c d <<<"$(ip_of "$1")"; printf '02:00:%02x:%02x:%02x:%02x' "$a" "$b" "$c" "$d"; }
name_of() { echo "$project-$1"; }

grpcurl_bin() {
  if [ -x "$root/.venv/bin/grpcurl" ]; then echo "$root/.venv/bin/grpcurl"; else command -v grpcurl || true; fi
}

preflight() {
  command -v podman >/dev/null ||
    die "podman is not installed: sudo apt-get install -y --no-install-recommends podman runc buildah debootstrap"
  [ "$(id -u)" -eq 0 ] || die "run as root: the containers run with rootful podman"
  [ -n "$(grpcurl_bin)" ] || die "grpcurl is missing: run deploy/setup-tools.sh (it installs it into .venv/bin)"
  for i in "$image" "$models_image"; do
    podman image exists "$i" || die "no image $i: build it with make images (or deploy/build-images.sh --tag $tag)"
  done
  case "$perception" in realistic | oracle | neural) ;; *) die "VLNAV_PERCEPTION=$perception: use realistic, oracle or neural" ;; esac
}

# vlnav-config's data as KEY=VALUE lines, without the collector's settings
# (no collector runs here).
configmap_env() {
  sed -n 's/^  \([A-Z][A-Z0-9_]*\): "\(.*\)"$/\1=\2/p' "$root/k8s/base/configmap.yaml" | grep -v '^OTEL_EXPORTER_'
}

# A Deployment's own `env:` (name/value pairs) as KEY=VALUE lines.
deployment_env() {
  awk '/^ *- name: / { n = $3; next }
       n != "" && /^ *value: / { v = $0; sub(/^ *value: /, "", v); gsub(/^"|"$/, "", v); print n "=" v }
       { n = "" }' "$root/k8s/base/$1.yaml"
}

# The perception stages' backends for VLNAV_PERCEPTION (vlnav::up::apply_perception).
perception_env() {
  case "$perception:$1" in
    oracle:detector) printf '%s\n' VLNAV_DETECTOR_BACKEND=sim VLNAV_DETECTOR_SIM_PROFILE=oracle ;;
    oracle:reid) printf '%s\n' VLNAV_REID_BACKEND=sim VLNAV_REID_SIM_PROFILE=oracle ;;
    oracle:segmenter) echo VLNAV_SEGMENTER_BACKEND=sim ;;
    realistic:detector) printf '%s\n' VLNAV_DETECTOR_BACKEND=sim VLNAV_DETECTOR_SIM_PROFILE=nanodet ;;
    realistic:reid) printf '%s\n' VLNAV_REID_BACKEND=sim VLNAV_REID_SIM_PROFILE=nanodet ;;
    realistic:segmenter) echo VLNAV_SEGMENTER_BACKEND=colour ;;
  esac
}

# Flags every container shares: the network, its fixed address, every
# Service name, and the manifests' security context.
common_flags() {
  local svc=$1 s n
  # shellcheck disable=SC2054 # the commas are tmpfs options
  FLAGS=(--name "$(name_of "$svc")" --label "$label" --label "io.vlnav.service=$svc" --hostname "$svc"
    --network "$network" --ip "$(ip_of "$svc")" --mac-address "$(mac_of "$svc")"
    --user 65532:65532 --read-only --read-only-tmpfs=false --tmpfs /tmp:rw,size=64m,mode=1777
    --cap-drop=all --security-opt=no-new-privileges)
  for s in "${SERVICES[@]}"; do
    for n in ${NAMES[$s]}; do FLAGS+=(--add-host "$n:$(ip_of "$s")"); done
  done
}

# The component's Secret (vlnav-<component>-tls) at /etc/vlnav/tls.
tls_flags() {
  local cert=$1 key=$2
  FLAGS+=(-v "$creds/ca.pem:/etc/vlnav/tls/ca.crt:ro" -v "$cert:/etc/vlnav/tls/tls.crt:ro"
    -v "$key:/etc/vlnav/tls/tls.key:ro")
}

credentials() {
  mkdir -p "$creds"
  chown 65532:65532 "$creds"
  chmod 0700 "$creds"
  local names=() n
  IFS=, read -ra extra <<<"${VLNAV_GATEWAY_NAMES:-}"
  for n in "${extra[@]}"; do [ -n "$n" ] && names+=(--gateway-name "$n"); done
  [ "$gw_address" != 127.0.0.1 ] && [ "$gw_address" != 0.0.0.0 ] && names+=(--gateway-name "$gw_address")
  podman run --rm --read-only --network none --user 65532:65532 -v "$creds:/out" "$image" \
    credentials k8s --out /out --robot "$robot" "${names[@]}" >/dev/null 2>&1 ||
    die "vlnav credentials k8s failed in $image"
}

wait_healthy() {
  local svc=$1 limit=${2:-300} started grpcurl out
  grpcurl=$(grpcurl_bin)
  started=$(date +%s)
  while :; do
    if [ "$(podman inspect --format '{{.State.Running}}' "$(name_of "$svc")" 2>/dev/null)" != true ]; then
      podman logs --tail 30 "$(name_of "$svc")" >&2 || true
      die "$svc is not running"
    fi
    # The probes' check: plaintext, health only, no reflection (hence the proto).
    out=$("$grpcurl" -plaintext -max-time 2 -import-path "$root/deploy/proto" -proto grpc/health/v1/health.proto \
      "$(ip_of "$svc"):8090" grpc.health.v1.Health/Check 2>/dev/null || true)
    [[ "$out" == *'"SERVING"'* ]] && return 0
    if [ $(($(date +%s) - started)) -ge "$limit" ]; then
      podman logs --tail 30 "$(name_of "$svc")" >&2 || true
      die "$svc did not answer its health check within $limit s"
    fi
    sleep 0.5
  done
}

run_service() {
  local svc=$1 kv
  common_flags "$svc"
  tls_flags "$creds/components/$svc.pem" "$creds/components/$svc-key.pem"
  while IFS= read -r kv; do FLAGS+=(-e "$kv"); done < <(configmap_env; deployment_env "$svc"; perception_env "$svc")
  FLAGS+=(-e "RUST_LOG=${RUST_LOG:-info}" -e NO_COLOR=1)
  [ -n "${MODELS[$svc]:-}" ] && FLAGS+=(-v "$project-models:/models:ro")
  case "$svc" in
    gateway)
      FLAGS+=(-v "$creds/tokens.toml:/etc/vlnav/tokens/tokens.toml:ro" -v "$project-missions:/data:U"
        -p "$gw_address:$gw_port:50051")
      ;;
    reid) FLAGS+=(-v "$project-reid:/var/lib/vlnav/reid:U") ;;
  esac
  podman run -d "${FLAGS[@]}" --entrypoint "/usr/local/bin/vlnav-$svc" "$image" >/dev/null
}

run_edge() {
  local kv
  common_flags edge
  tls_flags "$creds/robot-$robot.pem" "$creds/robot-$robot-key.pem"
  FLAGS+=(-e VLNAV_EDGE_GATEWAY=https://gateway:50051 -e "VLNAV_EDGE_ROBOT_ID=$robot" -e VLNAV_EDGE_DRIVER=sim
    -e VLNAV_TLS_CA=/etc/vlnav/tls/ca.crt -e VLNAV_TLS_CLIENT_CERT=/etc/vlnav/tls/tls.crt
    -e VLNAV_TLS_CLIENT_KEY=/etc/vlnav/tls/tls.key -e "RUST_LOG=${RUST_LOG:-info}" -e NO_COLOR=1)
  while IFS= read -r kv; do
    case "$kv" in VLNAV_EDGE_GATEWAY=* | VLNAV_EDGE_ROBOT_ID=* | VLNAV_EDGE_DRIVER=*) ;; *) FLAGS+=(-e "$kv") ;; esac
  done < <(env | grep '^VLNAV_EDGE_' || true)
  podman run -d "${FLAGS[@]}" --entrypoint /usr/local/bin/vlnav-edge "$image" >/dev/null
}

# Waits until the gateway lists the robot as connected.
wait_robot() {
  local grpcurl out started
  grpcurl=$(grpcurl_bin)
  started=$(date +%s)
  while :; do
    out=$("$grpcurl" -cacert "$creds/ca.pem" -H "authorization: Bearer $(cat "$creds/operator.token")" -max-time 2 \
      "127.0.0.1:$gw_port" vlnav.v1.FleetService/ListRobots 2>/dev/null || true)
    if tr -d ' \n' <<<"$out" | grep -q "\"robotId\":\"$robot\",\"connected\":true"; then return 0; fi
    if [ "$(podman inspect --format '{{.State.Running}}' "$(name_of edge)" 2>/dev/null)" != true ]; then
      podman logs --tail 30 "$(name_of edge)" >&2 || true
      die "the edge agent is not running"
    fi
    [ $(($(date +%s) - started)) -lt 120 ] || die "$robot did not attach to the gateway within 120 s"
    sleep 0.5
  done
}

down() {
  local ids
  mapfile -t ids < <(podman ps -aq --filter "label=$label")
  [ ${#ids[@]} -eq 0 ] || podman rm -f -t 3 "${ids[@]}" >/dev/null
  if podman network exists "$network"; then podman network rm -f "$network" >/dev/null; fi
  mapfile -t ids < <(podman volume ls -q --filter "label=$label")
  [ ${#ids[@]} -eq 0 ] || podman volume rm -f "${ids[@]}" >/dev/null
  return 0
}

up() {
  preflight
  local started svc
  started=$(date +%s)
  down
  podman network create --label "$label" --subnet "$subnet.0/24" --gateway "$subnet.1" "$network" >/dev/null ||
    die "cannot create network $network on $subnet.0/24 (taken? set VLNAV_SUBNET)"
  credentials
  for v in models missions reid; do podman volume create --label "$label" "$project-$v" >/dev/null; done
  # The pods' init container: the models image's files into the volume.
  say "models: $models_image into volume $project-models"
  podman run --rm --read-only --network none --user 65532:65532 --cap-drop=all \
    --security-opt=no-new-privileges -v "$project-models:/mnt/models:U" "$models_image" cp -a /models/. /mnt/models/
  for svc in "${SERVICES[@]}"; do
    [ "$svc" = gateway ] && continue
    run_service "$svc"
  done
  for svc in "${SERVICES[@]}"; do
    [ "$svc" = gateway ] && continue
    wait_healthy "$svc"
  done
  run_service gateway
  wait_healthy gateway
  run_edge
  wait_robot
  say "up in $(($(date +%s) - started)) s: $image ($perception perception), robot $robot attached"
  cat <<EOF
  gateway:  $gw_address:$gw_port (TLS; CA $creds/ca.pem, operator token $creds/operator.token)
  submit:   $(grpcurl_bin) -cacert $creds/ca.pem -H "authorization: Bearer \$(cat $creds/operator.token)" \\
              -d '{"robot_id":"$robot","text":"move 2 m ahead"}' $gw_address:$gw_port vlnav.v1.MissionService/SubmitMission
  logs:     podman logs -f $project-gateway        stop: $0 down
EOF
}

case "${1:-}" in
  up) up ;;
  down) down; say "down: $project" ;;
  status) podman ps -a --filter "label=$label" --format '{{.Names}}\t{{.Status}}\t{{.Ports}}' ;;
  kill)
    [ -n "${2:-}" ] || die "kill which service?"
    podman kill --signal KILL "$(name_of "$2")" >/dev/null
    ;;
  start)
    [ -n "${2:-}" ] || die "start which service?"
    podman start "$(name_of "$2")" >/dev/null
    if [ "$2" = edge ]; then wait_robot; else wait_healthy "$2" 120; fi
    ;;
  *) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 2 ;;
esac
