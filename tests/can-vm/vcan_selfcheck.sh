#!/bin/sh
# Proves the CAN VM harness end to end with can-utils, independent of tendril:
#   tests/can-vm/run.sh "$PWD/tests/can-vm/vcan_selfcheck.sh"
# Inside the VM it checks that vcan0 exists, that a classic frame sent with
# cansend arrives at candump unchanged, that a receive filter drops other IDs,
# and, when vcan0 is CAN FD capable (mtu 72) and vcan1 is classic (mtu 16),
# that an FD frame passes vcan0 and is refused by vcan1.
# Exits 0 when all hold, 1 naming the first that does not.
set -u

fail() {
  echo "vcan_selfcheck: FAIL: $*"
  exit 1
}
pass() { echo "vcan_selfcheck: ok: $*"; }

for tool in cansend candump ip timeout; do
  command -v "$tool" >/dev/null 2>&1 || fail "$tool not found in the host tree (apt-get install can-utils iproute2)"
done

scratch="$(mktemp -d)" || fail "mktemp"
trap 'rm -rf "$scratch"' EXIT

# expect_frame <iface[,filter]> <send iface> <expected candump -L text, a glob> <frames to send...>
# Sends the frames repeatedly (candump may not be listening yet on the first
# try) until candump has received one frame or 5 s passed, then compares.
expect_frame() {
  listen="$1" send_if="$2" expected="$3"
  shift 3
  out="$scratch/dump"
  : >"$out"
  timeout 10 candump -n 1 -L -T 5000 "$listen" >"$out" 2>&1 &
  dump_pid=$!
  tries=0
  while kill -0 "$dump_pid" 2>/dev/null && [ "$tries" -lt 50 ]; do
    for frame in "$@"; do
      cansend "$send_if" "$frame" || fail "cansend $send_if $frame failed"
    done
    tries=$((tries + 1))
    sleep 0.1
  done
  wait "$dump_pid"
  # candump -L prints "(<time>) <iface> <frame>".
  received="$(sed -n 's/^([0-9.]*) //p' "$out" | head -n 1)"
  # shellcheck disable=SC2254 # $expected is a pattern on purpose
  case "$received" in
    $expected) ;;
    *) fail "listening on $listen after sending $*: expected '$expected', got '$received' (candump said: $(cat "$out"))" ;;
  esac
}

ip -details link show vcan0 2>/dev/null | grep -q vcan || fail "vcan0 is missing or not a vcan interface"
[ "$(cat /sys/class/net/vcan0/operstate)" != down ] || fail "vcan0 is down"
pass "vcan0 exists and is up"

expect_frame vcan0 vcan0 "vcan0 123#DEADBEEF" "123#DEADBEEF"
pass "classic frame 123#DEADBEEF sent by cansend arrived at candump"

expect_frame vcan0 vcan0 "vcan0 12345678#0102" "12345678#0102"
pass "extended-ID frame arrived"

# Filter 321/7FF: the 123 frame sent first must be dropped, 321 must pass.
expect_frame "vcan0,321:7FF" vcan0 "vcan0 321#01" "123#AA" "321#01"
pass "a receive filter passes 0x321 and drops 0x123"

if [ "$(cat /sys/class/net/vcan0/mtu)" = 72 ]; then
  # Flags nibble: 1 = BRS as sent; newer kernels add 4 (CANFD_FDF) on receive.
  expect_frame vcan0 vcan0 "vcan0 123##[15]112233445566778899AABBCC" "123##1112233445566778899AABBCC"
  pass "CAN FD frame (12 bytes, BRS) arrived on vcan0 (mtu 72)"
fi
if [ -e /sys/class/net/vcan1 ] && [ "$(cat /sys/class/net/vcan1/mtu)" = 16 ]; then
  if cansend vcan1 "123##1112233445566778899AABBCC" >/dev/null 2>&1; then
    fail "vcan1 (mtu 16, classic) accepted a CAN FD frame"
  fi
  pass "CAN FD frame refused by classic vcan1 (mtu 16)"
fi

echo "vcan_selfcheck: PASS"
