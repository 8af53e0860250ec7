#!/usr/bin/env bash
# shellcheck disable=SC2016 # the '$...' strings in this file are meant literally
# Tests run.sh itself (on the host; boots the VM once):
#   - usage errors exit 2 before any VM starts;
#   - the command's exit status, stdout/stderr, arguments (spaces, quotes,
#     dollar signs), working directory and GTEST_*/TENDRIL_* variables reach
#     the caller / the command unchanged; /tmp is writable in the VM;
#     TENDRIL_CAN_VM=1 is set; vcan0 and vcan1 exist.
# Exits 0 when all hold, 1 naming each that does not.
set -uo pipefail

RUN_SH="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)/run.sh"
readonly RUN_SH
failures=0
check() {
  local what="$1"
  shift
  if "$@"; then
    echo "harness_test: ok: $what"
  else
    echo "harness_test: FAIL: $what"
    failures=$((failures + 1))
  fi
}

status_of() {
  "$@" >/dev/null 2>&1 </dev/null
  echo $?
}
check "no command -> 2" test "$(status_of "$RUN_SH")" = 2
check "relative path -> 2" test "$(status_of "$RUN_SH" bin/true)" = 2
check "missing file -> 2" test "$(status_of "$RUN_SH" /nonexistent/tendril-binary)" = 2
hidden_exe="$(mktemp /tmp/can-vm-harness.XXXXXX)"
trap 'rm -f "$hidden_exe"' EXIT
chmod +x "$hidden_exe"
check "executable under /tmp (hidden in the VM) -> 2" test "$(status_of "$RUN_SH" "$hidden_exe")" = 2
check "bad TENDRIL_CAN_VM_VCAN -> 2" \
  test "$(TENDRIL_CAN_VM_VCAN='vcan0:xl' status_of "$RUN_SH" /bin/true)" = 2

# One boot: a shell reports what it sees, then exits 42.
probe='printf "arg=[%s]\n" "$@"
echo "cwd=$PWD"
echo "probe=$TENDRIL_HARNESS_PROBE gtest=$GTEST_HARNESS_PROBE in_vm=$TENDRIL_CAN_VM"
echo scratch >/tmp/harness-probe && echo "tmp=writable"
for i in vcan0 vcan1; do echo "$i mtu=$(cat /sys/class/net/$i/mtu)"; done
echo "to stderr" >&2
exit 42'
expected='arg=[a b]
arg=[it'"'"'s]
arg=[$HOME]
arg=[]
cwd=/usr/share
probe=x y'"'"'z gtest=1 in_vm=1
tmp=writable
vcan0 mtu=72
vcan1 mtu=16
to stderr'
output="$(cd /usr/share && unset TENDRIL_CAN_VM_VCAN && TENDRIL_HARNESS_PROBE="x y'z" GTEST_HARNESS_PROBE=1 \
  "$RUN_SH" /bin/sh -c "$probe" sh "a b" "it's" '$HOME' "" 2>/dev/null </dev/null)"
status=$?
check "command's exit status 42 is run.sh's" test "$status" = 42
check "stdout, stderr, args, cwd, environment and /tmp as expected" test "$output" = "$expected"
if [[ $output != "$expected" ]]; then
  diff <(echo "$expected") <(echo "$output") | sed 's/^/harness_test:   /'
fi

if [[ $failures -gt 0 ]]; then
  echo "harness_test: $failures check(s) failed"
  exit 1
fi
echo "harness_test: PASS"
