#!/usr/bin/env bash
# E-stop latency under load (issue 30; a bench: it reports, it asserts no speed). Starts tendrild on a
# free loopback port (tests/api/server.sh) with a soft RLIMIT_NOFILE of 1024, the systemd default
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
trap stop_tendrild EXIT INT TERM
binary="${TENDRILD:-$repo_root/build/server/tendrild}"
if [ $# -gt 0 ] && [ "${1#--}" = "$1" ]; then binary="$1"; shift; fi
[ -d "$repo_root/node_modules/@foxglove/ws-protocol" ] || { echo "run 'npm ci' in $repo_root first" >&2; exit 2; }
server_nofile="${TENDRIL_ESTOP_NOFILE:-1024}"
ulimit -S -n "$server_nofile" || { echo "cannot set the soft descriptor limit to $server_nofile" >&2; exit 2; }
start_tendrild "$binary" || exit 1
ulimit -S -n "$(ulimit -H -n)"
echo "tendrild $binary; its descriptor limit $(awk '/Max open files/ {print $4}' /proc/"$tendrild_pid"/limits), the client's $(ulimit -S -n); $(nproc) cores, load average $(cut -d' ' -f1-3 /proc/loadavg)"
node "$here/estop_latency.mjs" "$@"
status=$?
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
if [ $status -ne 0 ]; then
  echo "--- last lines of the tendrild log ---" >&2
  tail -n 40 "$TENDRIL_LOG" >&2
fi
exit $status
