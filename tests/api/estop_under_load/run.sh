#!/usr/bin/env bash
# The e-stop under load (issue 30), a server of its own: the loads that once delayed the e-stop
# (quadratic JSON bodies, slow work on the network threads, idle connections) each run a few seconds
# while REST and WebSocket e-stops are timed (estop_under_load.test.mjs; ~40 s). Then SIGTERM must
# disable the drives and end the process cleanly.
# The server gets RLIMIT_NOFILE 1024, soft and hard (TENDRIL_ESTOP_NOFILE to change it), so the 2,000
# idle connections are more than its descriptors; the test client gets its shell's hard limit.
# Usage: tests/api/estop_under_load/run.sh [tendrild]
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../server.sh"
trap stop_tendrild EXIT INT TERM  # (and the wrapper: start_limited_tendrild)
binary="${1:-${TENDRILD:-$repo_root/build/server/tendrild}}"
[ -d "$repo_root/node_modules/@foxglove/ws-protocol" ] || { echo "run 'npm ci' in $repo_root first" >&2; exit 2; }

# shellcheck source=tests/api/estop_under_load/limited_server.sh
source "$here/limited_server.sh"
start_limited_tendrild "$binary" || exit 1

node --test --test-concurrency=1 "$here"/*.test.mjs
status=$?
check_clean_shutdown || status=1
if [ $status -ne 0 ]; then
  echo "--- last lines of the tendrild log ---" >&2
  tail -n 40 "$TENDRIL_LOG" >&2
fi
exit $status
