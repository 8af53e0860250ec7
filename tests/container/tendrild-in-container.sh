#!/usr/bin/env bash
# Stands in for the tendrild binary in tests/api/server.sh (scripts/test-container.sh passes it as
# the binary): runs tendril's container image instead, with the test's generated configuration.
# Usage (as server.sh calls it): tendrild-in-container.sh --config <dir>/server.json
# The image is $TENDRIL_IMAGE (default localhost/tendril:latest). The test folder is mounted at the same
# path, so the robot file's path holds; web, vendor and vessel paths are rewritten to the image's own,
# so the console and data under test are the image's, not the working tree's. The recordings folder of
# the test is the image's recordings volume. podman runs in the foreground and passes SIGTERM to
# tendrild, so server.sh's clean-shutdown check sees tendrild's own shutdown.
set -euo pipefail
[ "${1:-}" = --config ] && [ -n "${2:-}" ] || { echo "usage: $0 --config <server.json>" >&2; exit 2; }
config="$2"
dir="$(dirname "$config")"
image="${TENDRIL_IMAGE:-localhost/tendril:latest}"
port="$(jq -r '.listen | split(":") | last' "$config")"
jq '.web_root = "/opt/tendril/web" | .vendor_root = "/opt/tendril/node_modules"
    | .scene.vessel = "/opt/tendril/config/vessels/synthetic_ica.csv"
    | .openapi = "/opt/tendril/server/openapi/openapi.json"
    | .recording.directory = "/opt/tendril/recordings"' "$config" > "$dir/server.container.json"
# The image's user (uid 10001) writes calibrated robot files beside the robot file
# (tests/api/calibration.test.mjs) and the recordings: podman's :U gives the mounted host folders to
# that user, as a lab does for a host folder it mounts (docker/README.md). The image's own volumes
# need nothing of the kind (scripts/test-container.sh, "compose").
mkdir -p "$dir/recordings"
exec podman --runtime runc run --rm --name "tendril-test-$port" --network host \
  --cap-add SYS_NICE --cap-add IPC_LOCK --ulimit nofile=8192:8192 --ulimit nproc=8192:8192 \
  -v "$dir:$dir:U" -v "$dir/recordings:/opt/tendril/recordings:U" \
  -e TENDRIL_TOKEN -e "TENDRIL_HEALTH_URL=http://127.0.0.1:$port/api/v1/health" \
  "$image" --config "$dir/server.container.json"
