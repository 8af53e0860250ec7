#!/usr/bin/env bash
# API tests of the ultrasound arm (config/robots/us_arm.json, the serial_arm plug-in with its
# "ultrasound" section) beside the catheter in one tendrild, over REST and WebSocket: the sweep command,
# its refusals, a sweep begun while the catheter moves, /us_arm/sweep. A server of its own.
# Usage: tests/api/us_arm/run.sh [tendrild]
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../server.sh"
trap stop_tendrild EXIT INT TERM

[ -d "$repo_root/node_modules/@foxglove/ws-protocol" ] || { echo "run 'npm ci' in $repo_root first" >&2; exit 2; }
export TENDRIL_TEST_EXTRA_ROBOTS="$repo_root/config/robots/us_arm.json"
start_tendrild "${1:-${TENDRILD:-$repo_root/build/server/tendrild}}" || exit 1
node --test --test-concurrency=1 "$here"/*.test.mjs
status=$?
check_clean_shutdown || status=1
if [ $status -ne 0 ]; then
  echo "--- last lines of the tendrild log ---" >&2
  tail -n 40 "$TENDRIL_LOG" >&2
fi
exit $status
