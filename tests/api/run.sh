#!/usr/bin/env bash
# API tests: starts the given tendrild on a free port with a known token and the repo's config,
# runs the node tests in tests/api/ (REST with fetch, WebSocket with @foxglove/ws-protocol), and
# always stops the server. Usage: tests/api/run.sh [path/to/tendrild]  (default $TENDRILD, else
# build/server/tendrild)
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/server.sh"
recorded_workdir=""  # the first server's folder, kept while its recording is replayed
cleanup() {
  stop_tendrild
  if [ -n "$recorded_workdir" ] && [ -z "${KEEP_TENDRILD_LOG:-}" ]; then rm -rf "$recorded_workdir"; fi
}
trap cleanup EXIT INT TERM

[ -d "$repo_root/node_modules/@foxglove/ws-protocol" ] || { echo "run 'npm ci' in $repo_root first" >&2; exit 2; }
# The session is recorded (config "recording") and read back after the shutdown (after_shutdown/).
# Only here: the browser tests' server does not record, so it keeps the CPU the page needs.
export TENDRIL_TEST_RECORDING=true
binary="${1:-${TENDRILD:-$repo_root/build/server/tendrild}}"
start_tendrild "$binary" || exit 1
# One file at a time: the files share one server and its single robot.
node --test --test-concurrency=1 "$here"/*.test.mjs
status=$?
# Last: SIGTERM must disable the drives and end the process cleanly.
check_clean_shutdown || status=1
# Then the session recording of the whole run, read back by @mcap/core.
node --test "$here"/after_shutdown/*.test.mjs || status=1
# Then that recording replayed (tendrild --replay): its topics through the WebSocket, no robot commanded.
recorded_workdir="$tendrild_workdir"
replayed="$TENDRIL_RECORDING_DIR"
tendrild_workdir=""
if TENDRIL_TEST_RECORDING=false TENDRILD_ARGS="--config {config} --replay $replayed" start_tendrild "$binary"; then
  TENDRIL_REPLAYED_DIR="$replayed" node --test "$here"/replay/*.test.mjs || status=1
else
  status=1
fi
if [ $status -ne 0 ]; then
  echo "--- last lines of the tendrild log ---" >&2
  tail -n 40 "$TENDRIL_LOG" >&2
fi
exit $status
