#!/usr/bin/env bash
# Browser tests of the console: starts the given tendrild on a free port with a known token and the
# repo's config, runs tests/e2e/*.e2e.mjs in headless Chromium (playwright-core, no browser
# download: /usr/bin/chromium or $CHROMIUM), and always stops the server.
# A second tendrild keeps the shipped SIMULATED vessel (the first one runs in free space, see
# tests/api/server.sh) for the tests of holds that need wall contact: TENDRIL_VESSEL_URL and
# TENDRIL_VESSEL_TOKEN point at it.
# Usage: tests/e2e/run.sh [path/to/tendrild] (default $TENDRILD, else build/server/tendrild).
# Screenshots: tests/e2e/artifacts/ (git-ignored).
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../api/server.sh"
vessel_pid=""
vessel_workdir=""
stop_both() {
  stop_tendrild
  tendrild_pid="$vessel_pid"
  tendrild_workdir="$vessel_workdir"
  stop_tendrild
}
trap stop_both EXIT INT TERM

[ -d "$repo_root/node_modules/playwright-core" ] || { echo "run 'npm ci' in $repo_root first" >&2; exit 2; }
chromium_bin="${CHROMIUM:-/usr/bin/chromium}"
[ -x "$chromium_bin" ] || { echo "no Chromium at $chromium_bin (apt-get install chromium, or set CHROMIUM)" >&2; exit 2; }
binary="${1:-${TENDRILD:-$repo_root/build/server/tendrild}}"
TENDRIL_TEST_VESSEL=1 start_tendrild "$binary" || exit 1
vessel_pid="$tendrild_pid"
vessel_workdir="$tendrild_workdir"
export TENDRIL_VESSEL_URL="$TENDRIL_URL" TENDRIL_VESSEL_TOKEN="$TENDRIL_TOKEN" TENDRIL_VESSEL_LOG="$TENDRIL_LOG"
tendrild_pid=""
tendrild_workdir=""
start_tendrild "$binary" || exit 1
node --test --test-concurrency=1 "$here"/*.e2e.mjs
status=$?
if [ $status -ne 0 ]; then
  echo "--- last lines of the tendrild log ---" >&2
  tail -n 40 "$TENDRIL_LOG" >&2
  echo "--- last lines of the tendrild log (with the vessel) ---" >&2
  tail -n 20 "$TENDRIL_VESSEL_LOG" >&2
fi
exit $status
