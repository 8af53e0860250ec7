#!/usr/bin/env bash
# Builds tendril's container image with podman and tests it (on demand; README, "Container"):
#   1. makes the debian:12 base image if podman has none (debootstrap --variant=minbase bookworm,
#      podman import; no registry is needed),
#   2. builds docker/Dockerfile and reports the build time and the image size,
#   3. runs the image with the API tests' configuration and runs the API tests against it, checks the
#      HEALTHCHECK, stops it with SIGTERM (the drives must be disabled) and reads back the session it
#      recorded on its recordings volume,
#   4. runs the image again and runs the console's browser test (tests/e2e/console.e2e.mjs) against it.
# Needs root (podman, debootstrap). Installs what it needs with scripts/install-deps.sh.
# Environment: TENDRIL_IMAGE (default localhost/tendril:test), TENDRIL_REBUILD_BASE=1 to remake the base,
# TENDRIL_SKIP_BUILD=1 to test the image already built.
set -uo pipefail
cd "$(dirname "$0")/.."
repo_root="$(pwd)"
scripts/install-deps.sh --tests --container || exit 1

image="${TENDRIL_IMAGE:-localhost/tendril:test}"
export TENDRIL_IMAGE="$image"
base=docker.io/library/debian:12
# runc: crun fails on this kind of virtual machine with "setrlimit: Operation not permitted".
podman=(podman --runtime runc)

stage() { printf '\n== %s\n' "$*"; }

if [ -n "${TENDRIL_REBUILD_BASE:-}" ] || ! "${podman[@]}" image exists "$base"; then
  stage "base image $base (debootstrap --variant=minbase bookworm)"
  rootfs="$(mktemp -d /var/tmp/tendril-rootfs.XXXXXX)"
  trap 'rm -rf "$rootfs"' EXIT
  t0=$(date +%s)
  debootstrap --variant=minbase bookworm "$rootfs" http://deb.debian.org/debian > "$rootfs.log" 2>&1 || {
    echo "debootstrap failed; its log: $rootfs.log" >&2; exit 1; }
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
unset TENDRIL_TEST_RECORDING

stage "console browser test against the container"
start_tendrild "$stand_in" || exit 1
node --test --test-concurrency=1 tests/e2e/console.e2e.mjs || status=1
stop_tendrild

stage "summary"
echo "image $image: built in ${build_s}, $(( size_bytes / 1000000 )) MB"
[ $status -eq 0 ] && echo "container tests passed" || echo "container tests FAILED"
exit $status
