#!/usr/bin/env bash
# Soak test (on demand, not part of scripts/test.sh): the default server, exactly as scripts/run.sh
# configures it (config/server.json: the SIMULATED SRMC in its vessel, imaging on, real-time priority
# requested), left running with the console open in headless Chromium and a Foxglove WebSocket
# client streaming every channel, while the robot is enabled and makes a small move now and then.
# Passes when nothing faulted or held the robot by itself; prints the control loop's statistics
# (period error p50/p99/max, overruns, late cycles, longest lost control time), the server's CPU per
# thread and its resident memory, and writes them to tests/soak/artifacts/soak-<time>.json.
#
#   tests/soak/run.sh [--minutes N] [--move-every S] [path/to/tendrild]
#     --minutes N      how long (default 60)
#     --move-every S   a 2 mm insertion move out and back every S seconds, 0 = stay at rest (default 60)
#     tendrild         default build-release/server/tendrild (scripts/run.sh builds it)
#
# Run it on a machine doing its ordinary work (other builds and tests): that is the point.
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
minutes=60
move_every=60
binary=""
while [ $# -gt 0 ]; do
  case "$1" in
    --minutes) minutes="$2"; shift 2 ;;
    --move-every) move_every="$2"; shift 2 ;;
    -h|--help) sed -n '2,15p' "$0"; exit 0 ;;
    *) binary="$1"; shift ;;
  esac
done
# shellcheck source=tests/api/server.sh
source "$here/../api/server.sh"
trap stop_tendrild EXIT INT TERM
binary="${binary:-${TENDRILD:-$repo_root/build-release/server/tendrild}}"

[ -d "$repo_root/node_modules/playwright-core" ] || { echo "run 'npm ci' in $repo_root first" >&2; exit 2; }
chromium_bin="${CHROMIUM:-/usr/bin/chromium}"
[ -x "$chromium_bin" ] || { echo "no Chromium at $chromium_bin (apt-get install chromium, or set CHROMIUM)" >&2; exit 2; }

# The shipped configuration, not the test one: only the port and the token differ.
export TENDRILD_ARGS="--config config/server.json --listen 127.0.0.1:{port} --token {token}"
start_tendrild "$binary" || exit 1
mkdir -p "$here/artifacts"
TENDRIL_PID="$tendrild_pid" SOAK_MINUTES="$minutes" SOAK_MOVE_EVERY="$move_every" \
  SOAK_REPORT="$here/artifacts/soak-$(date -u +%Y%m%dT%H%M%SZ).json" node "$here/soak.mjs"
status=$?
check_clean_shutdown || status=1
if [ $status -ne 0 ]; then
  echo "--- last lines of the tendrild log ---" >&2
  tail -n 40 "$TENDRIL_LOG" >&2
fi
exit $status
