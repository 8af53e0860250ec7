#!/usr/bin/env bash
# shellcheck disable=SC2016 # the '$...' strings in this file are meant literally
# Tests run.sh itself (on the host; boots the VM twice):
#   - usage errors exit 2 before any VM starts;
#   - the command's exit status, stdout/stderr, arguments (spaces, quotes,
#     dollar signs), working directory and GTEST_*/TENDRIL_* variables reach
#     the caller / the command unchanged; /tmp is writable in the VM;
#     TENDRIL_CAN_VM=1 is set; vcan0 and vcan1 exist;
#   - a command in a folder under /tmp (a clone in /tmp/fresh) runs, from there.
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
run_exe="$(mktemp /run/can-vm-harness.XXXXXX)"
chmod +x "$run_exe"
check "executable under /run (a fresh tmpfs in the VM) -> 2" test "$(status_of "$RUN_SH" "$run_exe")" = 2
rm -f "$run_exe"
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

# A second boot: a command in a folder under /tmp (a clone in /tmp/fresh), run from there, still runs;
# the rest of /tmp is the VM's own, empty and writable.
tmp_clone="$(mktemp -d /tmp/can-vm-harness.XXXXXX)"
trap 'rm -rf "$tmp_clone"' EXIT
mkdir "$tmp_clone/bin"
printf '#!/bin/sh\necho "ran=$(basename "$0") cwd=$(basename "$PWD")"\necho "others=$(ls /tmp | grep -vc can-vm-harness)"\n: >/tmp/probe && echo tmp=writable\nexit 7\n' >"$tmp_clone/bin/probe"
chmod +x "$tmp_clone/bin/probe"
output="$(cd "$tmp_clone" && "$RUN_SH" "$tmp_clone/bin/probe" 2>/dev/null </dev/null)"
status=$?
check "a command in a clone under /tmp runs there (exit 7)" test "$status" = 7
expected="ran=probe cwd=$(basename "$tmp_clone")
others=0
tmp=writable"
check "it runs in its clone's folder, and the rest of /tmp is the VM's own, empty and writable" test "$output" = "$expected"
if [[ $output != "$expected" ]]; then
  diff <(echo "$expected") <(echo "$output") | sed 's/^/harness_test:   /'
fi

if [[ $failures -gt 0 ]]; then
  echo "harness_test: $failures check(s) failed"
  exit 1
fi
echo "harness_test: PASS"
