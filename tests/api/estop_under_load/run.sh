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
trap stop_tendrild EXIT INT TERM  # (and the wrapper, below)
binary="${1:-${TENDRILD:-$repo_root/build/server/tendrild}}"
[ -d "$repo_root/node_modules/@foxglove/ws-protocol" ] || { echo "run 'npm ci' in $repo_root first" >&2; exit 2; }

# The server runs with RLIMIT_NOFILE 1024, soft and hard (the systemd default soft limit; hard too, so
# that a server raising its soft limit cannot step out of the attack): started through a wrapper that
# sets it. TENDRIL_ESTOP_NOFILE changes it. The client keeps this shell's limit (it holds 2,000).
server_nofile="${TENDRIL_ESTOP_NOFILE:-1024}"
wrapper_dir="$(mktemp -d /tmp/tendril-estop-load.XXXXXX)"
trap 'stop_tendrild; rm -rf "$wrapper_dir"' EXIT INT TERM
[ -x "$binary" ] || { echo "usage: $0 [path to tendrild]   ('$binary' is not an executable file)" >&2; exit 2; }
binary="$(cd "$(dirname "$binary")" && pwd)/$(basename "$binary")"
printf '#!/bin/sh\nulimit -n %s || exit 2\nexec "%s" "$@"\n' "$server_nofile" "$binary" > "$wrapper_dir/tendrild"
chmod +x "$wrapper_dir/tendrild"
start_tendrild "$wrapper_dir/tendrild" || exit 1
ulimit -S -n "$(ulimit -H -n)"  # the client's own limit, as high as allowed
echo "tendrild $binary: descriptor limit $(awk '/Max open files/ {print $4 " soft, " $5 " hard"}' /proc/"$tendrild_pid"/limits); the test client's $(ulimit -S -n)"

node --test --test-concurrency=1 "$here"/*.test.mjs
status=$?
check_clean_shutdown || status=1
if [ $status -ne 0 ]; then
  echo "--- last lines of the tendrild log ---" >&2
  tail -n 40 "$TENDRIL_LOG" >&2
fi
exit $status
