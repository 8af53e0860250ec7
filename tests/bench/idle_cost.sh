#!/usr/bin/env bash
# What an idle default server costs: tendrild with config/server.json (the SIMULATED SRMC, imaging on,
# real-time priority requested), no client connected, measured over SECONDS after a settling time.
# Prints the share of one core per thread (from /proc/PID/task/*/stat, summed by thread name), the
# total, and the resident memory. A benchmark: it reports, it asserts nothing.
#   tests/bench/idle_cost.sh [--seconds N] [path/to/tendrild]   (default 60 s, build-release/server/tendrild)
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
seconds=60
binary=""
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    -h|--help) sed -n '2,6p' "$0"; exit 0 ;;
    *) binary="$1"; shift ;;
  esac
done
# shellcheck source=tests/api/server.sh
source "$here/../api/server.sh"
trap stop_tendrild EXIT INT TERM
binary="${binary:-${TENDRILD:-$repo_root/build-release/server/tendrild}}"
export TENDRILD_ARGS="--config config/server.json --listen 127.0.0.1:{port} --token {token}"
start_tendrild "$binary" || exit 1
sleep 5  # start-up done, caches warm

ticks() {  # name ticks, one line per thread
  for stat in /proc/"$tendrild_pid"/task/*/stat; do
    local line name rest
    line="$(cat "$stat" 2>/dev/null)" || continue
    name="${line#*(}"; name="${name%%)*}"
    rest="${line##*) }"
    # shellcheck disable=SC2086
    set -- $rest
    echo "${name// /_} $((${12} + ${13}))"
  done | awk '{t[$1] += $2} END {for (n in t) print n, t[n]}'
}
before="$(ticks)"
sleep "$seconds"
after="$(ticks)"
hz="$(getconf CLK_TCK)"
echo "idle tendrild, ${seconds} s, share of one core per thread:"
join <(sort <<<"$before") <(sort <<<"$after") |
  awk -v s="$seconds" -v hz="$hz" '{p = ($3 - $2) / hz / s * 100; total += p; printf "  %-16s %6.2f %%\n", $1, p}
       END {printf "  %-16s %6.2f %%\n", "total", total}' | sort -k2 -n -r
grep -E 'VmRSS|VmLck|Threads' /proc/"$tendrild_pid"/status | sed 's/^/  /'
