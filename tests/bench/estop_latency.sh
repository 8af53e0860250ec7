#!/usr/bin/env bash
# E-stop latency under load (issue 30; a bench: it reports, it asserts no speed). Starts tendrild on a
# free loopback port (tests/api/server.sh) with RLIMIT_NOFILE 1024, soft and hard
# (TENDRIL_ESTOP_NOFILE), then tests/bench/estop_latency.mjs times REST and WebSocket e-stops under
# each load class of the CI suite tests/api/estop_under_load/ (the same loads, longer: 100 rounds of a
# REST and a WebSocket e-stop per class, i.e. 200 e-stops), and prints class → REST and WS p50/p99/max,
# the p99 against idle's and the issue's target (p99 ≤ 50 ms). Exits 1 only when an e-stop went
# unanswered or was refused. Takes about 3 minutes on 2 cores (20 s of each load). In scripts/test.sh --full.
#   tests/bench/estop_latency.sh [path/to/tendrild] [estop_latency.mjs options: --rounds N --only side_view,...]
# A release build gives the figures to quote (e.g. build-gcc/server/tendrild from scripts/test.sh --full,
# or a Release tree of your own); the default is the sanitized build/server/tendrild.
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../api/server.sh"
trap stop_tendrild EXIT INT TERM  # (and the wrapper: start_limited_tendrild)
binary="${TENDRILD:-$repo_root/build/server/tendrild}"
if [ $# -gt 0 ] && [ "${1#--}" = "$1" ]; then binary="$1"; shift; fi
[ -d "$repo_root/node_modules/@foxglove/ws-protocol" ] || { echo "run 'npm ci' in $repo_root first" >&2; exit 2; }
# shellcheck source=tests/api/estop_under_load/limited_server.sh
source "$here/../api/estop_under_load/limited_server.sh"
start_limited_tendrild "$binary" || exit 1
echo "$(nproc) cores, load average $(cut -d' ' -f1-3 /proc/loadavg)"
node "$here/estop_latency.mjs" "$@"
status=$?
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
if [ $status -ne 0 ]; then
  echo "--- last lines of the tendrild log ---" >&2
  tail -n 40 "$TENDRIL_LOG" >&2
fi
exit $status
