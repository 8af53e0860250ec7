#!/usr/bin/env bash
# Builds tendril's container image with podman and tests it (on demand; README, "Container"):
#   1. makes the debian:12 base image if podman has none (debootstrap --variant=minbase bookworm with
#      bookworm-updates and bookworm-security, podman import; no registry is needed),
#   2. builds docker/Dockerfile and reports the build time and the image size,
#   3. runs the image with the API tests' configuration and runs the API tests against it, checks the
#      HEALTHCHECK, stops it with SIGTERM (the drives must be disabled) and reads back the session it
#      recorded on its recordings volume,
#   4. runs the image again and runs the console's browser test (tests/e2e/console.e2e.mjs) against it,
#   5. brings docker/compose.yaml up as written (podman-compose): health, the second DDS participant, a
#      calibration saved on the configuration volume with nothing chmod-ed, down within the grace
#      period, and the calibration still there in new containers.
# Needs root (podman, debootstrap). Installs what it needs with scripts/install-deps.sh.
# Environment: TENDRIL_IMAGE (default localhost/tendril:latest, the image docker/compose.yaml runs),
# TENDRIL_REBUILD_BASE=1 to remake the base,
# TENDRIL_SKIP_BUILD=1 to test the image already built.
set -uo pipefail
cd "$(dirname "$0")/.."
repo_root="$(pwd)"
scripts/install-deps.sh --tests --container || exit 1

image="${TENDRIL_IMAGE:-localhost/tendril:latest}"
export TENDRIL_IMAGE="$image"
base=docker.io/library/debian:12
# runc: crun fails on this kind of virtual machine with "setrlimit: Operation not permitted".
podman=(podman --runtime runc)

stage() { printf '\n== %s\n' "$*"; }

if [ -n "${TENDRIL_REBUILD_BASE:-}" ] || ! "${podman[@]}" image exists "$base"; then
  stage "base image $base (debootstrap --variant=minbase bookworm, with bookworm-updates and bookworm-security)"
  rootfs="$(mktemp -d /var/tmp/tendril-rootfs.XXXXXX)"
  trap 'rm -rf "$rootfs"' EXIT
  t0=$(date +%s)
  debootstrap --variant=minbase bookworm "$rootfs" http://deb.debian.org/debian > "$rootfs.log" 2>&1 || {
    echo "debootstrap failed; its log: $rootfs.log" >&2; exit 1; }
  # debootstrap writes a sources.list with "bookworm main" alone: an image built on it would never get
  # a security fix. The same sources as Debian's own debian:12 image instead.
  rm -f "$rootfs/etc/apt/sources.list"
  cp docker/debian.sources "$rootfs/etc/apt/sources.list.d/debian.sources"
  # As in Debian's debian:12 image: apt deletes the packages it downloaded once they are installed
  # and keeps no package caches, so no image layer carries them.
  cat > "$rootfs/etc/apt/apt.conf.d/docker-clean" <<'APTCONF'
DPkg::Post-Invoke { "rm -f /var/cache/apt/archives/*.deb /var/cache/apt/archives/partial/*.deb /var/cache/apt/*.bin || true"; };
APT::Update::Post-Invoke { "rm -f /var/cache/apt/archives/*.deb /var/cache/apt/archives/partial/*.deb /var/cache/apt/*.bin || true"; };
Dir::Cache::pkgcache "";
Dir::Cache::srcpkgcache "";
APTCONF
  echo 'Acquire::Languages "none";' > "$rootfs/etc/apt/apt.conf.d/docker-no-languages"
  rm -rf "$rootfs"/var/lib/apt/lists/* "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/cache/apt/*.bin
  tar -C "$rootfs" -c . | "${podman[@]}" import - "$base" > /dev/null || exit 1
  rm -rf "$rootfs" "$rootfs.log"
  trap - EXIT
  echo "made $base in $(( $(date +%s) - t0 )) s"
fi

if [ -n "${TENDRIL_SKIP_BUILD:-}" ] && "${podman[@]}" image exists "$image"; then
  stage "using the existing $image (TENDRIL_SKIP_BUILD)"
  build_s="(not built)"
else
stage "build $image (docker/Dockerfile)"
# The npm registry may be reached through a proxy only the host's CA bundle trusts: mount the bundle
# for the build and point node at it; it is never copied into the image.
ca=()
if [ -r /etc/ssl/certs/ca-certificates.crt ]; then
  ca=(-v /etc/ssl/certs/ca-certificates.crt:/run/host-ca.crt:ro --build-arg NODE_EXTRA_CA_CERTS=/run/host-ca.crt)
fi
t0=$(date +%s)
"${podman[@]}" build --format docker --network host "${ca[@]}" -f docker/Dockerfile -t "$image" . || {
  echo "podman build failed" >&2; exit 1; }
build_s="$(( $(date +%s) - t0 )) s"
fi
size_bytes="$("${podman[@]}" image inspect --format '{{.Size}}' "$image")"
echo "built $image in ${build_s}; image size $(( size_bytes / 1000000 )) MB"

# The tests start "tendrild" through tests/api/server.sh; the stand-in runs the image instead.
# shellcheck source=tests/api/server.sh
source "$repo_root/tests/api/server.sh"
cleanup() { stop_tendrild; "${podman[@]}" ps -a --format '{{.Names}}' | grep '^tendril-test-' |
  xargs -r "${podman[@]}" rm -f > /dev/null 2>&1; }
trap cleanup EXIT INT TERM
stand_in="$repo_root/tests/container/tendrild-in-container.sh"
status=0

stage "API tests against the container"
export TENDRIL_TEST_RECORDING=true
start_tendrild "$stand_in" || exit 1
name="tendril-test-${TENDRIL_URL##*:}"
# TENDRIL_PID is the podman client; the API tests read the control thread's scheduling from tendrild.
TENDRIL_SERVER_PID="$("${podman[@]}" inspect --format '{{.State.Pid}}' "$name")"
export TENDRIL_SERVER_PID
grep -h "control loop" "$TENDRIL_LOG" | sed 's/^/  tendrild said: /'
# The HEALTHCHECK the image declares, run as the engine runs it.
if "${podman[@]}" healthcheck run "$name" > /dev/null; then
  echo "ok - HEALTHCHECK: $name is healthy"
else
  echo "not ok - HEALTHCHECK of $name failed"; status=1
fi
user="$("${podman[@]}" exec "$name" id -un)"
if [ "$user" = tendril ]; then echo "ok - tendrild runs as user '$user'"; else
  echo "not ok - tendrild runs as '$user', not the image's non-root user"; status=1; fi
# A second DDS participant in its own container (the compose file's dds-subscriber): the image's
# tendril-dds-probe reads five joint states of the container's tendrild over DDS.
# The same rlimits as the server's container (tests/container/tendrild-in-container.sh): runc on this
# kind of virtual machine cannot raise them to the engine's defaults ("error setting rlimit type 7").
if "${podman[@]}" run --rm --network host --ulimit nofile=8192:8192 --ulimit nproc=8192:8192 \
     --entrypoint /opt/tendril/bin/tendril-dds-probe \
     "$image" --timeout 20 echo srmc joint_states --count 5 \
     > /dev/null; then
  echo "ok - a second container's DDS participant reads rt/srmc/joint_states"
else
  echo "not ok - no joint states over DDS in a second container"; status=1
fi
node --test --test-concurrency=1 tests/api/*.test.mjs || status=1
check_clean_shutdown || status=1
node --test tests/api/after_shutdown/*.test.mjs || status=1
unset TENDRIL_TEST_RECORDING TENDRIL_SERVER_PID

stage "console browser test against the container"
start_tendrild "$stand_in" || exit 1
node --test --test-concurrency=1 tests/e2e/console.e2e.mjs || status=1
stop_tendrild

stage "compose: docker/compose.yaml as written (podman-compose)"
# The compose file's own project, volumes and containers, under a name of this run; its port on
# loopback is a free one, and its token is known to the test.
compose_project="tendril-compose-test-$$"
compose=(podman-compose --podman-args="--runtime runc" -p "$compose_project" -f docker/compose.yaml)
export TENDRIL_PORT TENDRIL_TOKEN TENDRIL_URL
TENDRIL_PORT="$(free_port)"
TENDRIL_TOKEN="compose-$(od -An -N12 -tx1 /dev/urandom | tr -d ' \n')"
TENDRIL_URL="http://127.0.0.1:$TENDRIL_PORT"
compose_server="${compose_project}_tendrild_1"
compose_subscriber="${compose_project}_dds-subscriber_1"
compose_down() { "${compose[@]}" down "$@" > "$compose_log.down" 2>&1; }
compose_log="$(mktemp /tmp/tendril-compose.XXXXXX)"
trap 'cleanup; compose_down -v; rm -f "$compose_log" "$compose_log.down"' EXIT INT TERM
wait_health() {  # bounded: 150 tries 0.2 s apart
  for _ in $(seq 150); do
    curl -fsS "$TENDRIL_URL/api/v1/health" > /dev/null 2>&1 && return 0
    sleep 0.2
  done
  return 1
}
if "${compose[@]}" up -d > "$compose_log" 2>&1 && wait_health; then
  echo "ok - compose up: tendrild answers on 127.0.0.1:$TENDRIL_PORT"
  "${podman[@]}" logs "$compose_server" 2>&1 | grep -h "control loop" | sed 's/^/  tendrild said: /'
  if "${podman[@]}" healthcheck run "$compose_server" > /dev/null; then
    echo "ok - compose: the tendrild service is healthy"
  else echo "not ok - compose: the tendrild service's HEALTHCHECK failed"; status=1; fi
  hc="$("${podman[@]}" inspect --format '{{.Config.Healthcheck}}' "$compose_subscriber")"
  if [ "$hc" = "<nil>" ] || [ "$hc" = "" ] || grep -q NONE <<< "$hc"; then
    echo "ok - compose: dds-subscriber has no health check of tendrild's"
  else echo "not ok - compose: dds-subscriber inherits a health check: $hc"; status=1; fi
  # Its joint states over DDS, across the two containers (bounded: 100 tries). grep -c reads the whole
  # log: grep -q would stop early, and podman's SIGPIPE would fail the pipeline under pipefail.
  joint_states() { "${podman[@]}" logs "$compose_subscriber" 2>/dev/null | grep -c '"position"'; }
  for _ in $(seq 100); do
    [ "$(joint_states)" -gt 0 ] && break
    sleep 0.2
  done
  if [ "$(joint_states)" -gt 0 ]; then
    echo "ok - compose: dds-subscriber prints tendrild's joint states"
  else echo "not ok - compose: no joint states in dds-subscriber's log"; status=1; fi
  calibration="srmc-calibrated-compose-$$.json"
  TENDRIL_CALIBRATION_FILE="$calibration" node --test tests/container/calibration_on_config_volume.test.mjs || status=1
  t0=$(date +%s%N)
  "${compose[@]}" stop > "$compose_log.down" 2>&1
  stop_ms=$(( ($(date +%s%N) - t0) / 1000000 ))
  # 10 s is the grace period: a service that ignored SIGTERM is killed only then.
  if [ "$stop_ms" -lt 8000 ]; then echo "ok - compose stop in $stop_ms ms (no service waited for SIGKILL)"
  else echo "not ok - compose stop took $stop_ms ms"; status=1; fi
  if "${podman[@]}" logs "$compose_server" 2>&1 | grep -q "drives disabled, stopped cleanly"; then
    echo "ok - compose stop: tendrild disabled the drives"
  else echo "not ok - compose stop: tendrild did not say it disabled the drives"; status=1; fi
  compose_down
  # New containers on the same volumes: the calibrated robot file is still there.
  if "${compose[@]}" up -d > "$compose_log" 2>&1 && wait_health &&
     "${podman[@]}" exec "$compose_server" test -s "/opt/tendril/config/robots/$calibration"; then
    echo "ok - compose: the calibration saved on the configuration volume is there in new containers"
  else echo "not ok - compose: the calibration did not survive into new containers"; status=1; fi
else
  echo "not ok - compose up: tendrild did not answer; podman-compose said:"; tail -n 20 "$compose_log"; status=1
fi
compose_down -v
unset TENDRIL_PORT

stage "summary"
echo "image $image: built in ${build_s}, $(( size_bytes / 1000000 )) MB"
[ $status -eq 0 ] && echo "container tests passed" || echo "container tests FAILED"
exit $status
