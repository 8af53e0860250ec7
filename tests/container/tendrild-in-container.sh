#!/usr/bin/env bash
# Stands in for the tendrild binary in tests/api/server.sh (scripts/test-container.sh passes it as
# the binary): runs tendril's container image instead, with the test's generated configuration.
# Usage (as server.sh calls it): tendrild-in-container.sh --config <dir>/server.json
# The image is $TENDRIL_IMAGE (default localhost/tendril:test). The test folder is mounted at the same
# path, so the robot file's path holds; web, vendor and vessel paths are rewritten to the image's own,
# so the console and data under test are the image's, not the working tree's. The recordings folder of
# the test is the image's recordings volume. podman runs in the foreground and passes SIGTERM to
# tendrild, so server.sh's clean-shutdown check sees tendrild's own shutdown.
set -euo pipefail
[ "${1:-}" = --config ] && [ -n "${2:-}" ] || { echo "usage: $0 --config <server.json>" >&2; exit 2; }
config="$2"
dir="$(dirname "$config")"
image="${TENDRIL_IMAGE:-localhost/tendril:test}"
port="$(jq -r '.listen | split(":") | last' "$config")"
jq '.web_root = "/opt/tendril/web" | .vendor_root = "/opt/tendril/node_modules"
    | .scene.vessel = "/opt/tendril/config/vessels/synthetic_ica.csv"
    | .openapi = "/opt/tendril/server/openapi/openapi.json"
    | .recording.directory = "/opt/tendril/recordings"' "$config" > "$dir/server.container.json"
# mktemp made the folder 0700; the image's user (uid 10001) reads it, writes calibrated robot files
# beside the robot file (tests/api/calibration.test.mjs) and writes the recordings.
mkdir -p "$dir/recordings"
chmod 0777 "$dir" "$dir/recordings"
exec podman --runtime runc run --rm --name "tendril-test-$port" --network host \
  --cap-add SYS_NICE --cap-add IPC_LOCK --ulimit nofile=8192:8192 --ulimit nproc=8192:8192 \
  -v "$dir:$dir" -v "$dir/recordings:/opt/tendril/recordings" \
  -e TENDRIL_TOKEN -e "TENDRIL_HEALTH_URL=http://127.0.0.1:$port/api/v1/health" \
  "$image" --config "$dir/server.container.json"
