# Sourced by tests/api/estop_under_load/run.sh and tests/bench/estop_latency.sh (after tests/api/server.sh):
# start_limited_tendrild BINARY starts tendrild with RLIMIT_NOFILE 1024, soft and hard (the systemd default
# soft limit; hard too, so that a server raising its soft limit cannot step out of the attack), through a
# wrapper that sets it; TENDRIL_ESTOP_NOFILE changes it. Then this shell (the client, which holds 2,000
# connections) takes its hard limit. The EXIT trap stops the server and removes the wrapper.
start_limited_tendrild() {
  local binary=$1
  local server_nofile="${TENDRIL_ESTOP_NOFILE:-1024}"
  [ -x "$binary" ] || { echo "usage: $0 [path to tendrild]   ('$binary' is not an executable file)" >&2; return 2; }
  binary="$(cd "$(dirname "$binary")" && pwd)/$(basename "$binary")"
  limited_wrapper_dir="$(mktemp -d /tmp/tendril-estop-load.XXXXXX)"
  trap 'stop_tendrild; rm -rf "$limited_wrapper_dir"' EXIT INT TERM
  printf '#!/bin/sh\nulimit -n %s || exit 2\nexec "%s" "$@"\n' "$server_nofile" "$binary" > "$limited_wrapper_dir/tendrild"
  chmod +x "$limited_wrapper_dir/tendrild"
  start_tendrild "$limited_wrapper_dir/tendrild" || return 1
  ulimit -S -n "$(ulimit -H -n)"
  echo "tendrild $binary: descriptor limit $(awk '/Max open files/ {print $4 " soft, " $5 " hard"}' /proc/"$tendrild_pid"/limits); the client's $(ulimit -S -n)"
}
