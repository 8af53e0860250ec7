#!/usr/bin/env bash
# Sets up and runs every tendril test: installs what is missing, builds, then runs
#   1. unit, integration and server tests (ctest), including SocketCAN inside a qemu VM
#   2. REST + Foxglove WebSocket API tests against a running tendrild (node, @foxglove/ws-protocol)
#   3. the browser test (Playwright + Debian chromium), screenshots in tests/e2e/artifacts/
#   4. unit + integration tests again under AddressSanitizer + UndefinedBehaviorSanitizer
#   5. libFuzzer targets for every outside-input parser, for a bounded time
#   6. clang-format and clang-tidy
# Options: --quick skips 4-6. Ends with a line "tests: N passed, M failed".
set -uo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
quick=0
[ "${1:-}" = "--quick" ] && quick=1
jobs=$(nproc)
passed=0
failed=0
failed_steps=()

step() { echo; echo "=== $* ==="; }
record() {  # record <name> <status> <passed-count> <failed-count>
  passed=$((passed + $3))
  failed=$((failed + $4))
  if [ "$2" -ne 0 ]; then
    failed_steps+=("$1")
    [ "$4" -gt 0 ] || failed=$((failed + 1))
  fi
}
ctest_counts() {  # parses "X% tests passed, F tests failed out of N"
  local line total fail
  line=$(grep -E 'tests passed, [0-9]+ tests? failed out of [0-9]+' "$1" | tail -n 1)
  total=$(sed -E 's/.*out of ([0-9]+).*/\1/' <<<"$line")
  fail=$(sed -E 's/.*passed, ([0-9]+) tests? failed.*/\1/' <<<"$line")
  echo "$(( ${total:-0} - ${fail:-0} )) ${fail:-0}"
}
node_counts() {  # node --test prints "# pass N" and "# fail N"
  local p f
  p=$(grep -E '^# pass [0-9]+' "$1" | tail -n 1 | awk '{print $3}')
  f=$(grep -E '^# fail [0-9]+' "$1" | tail -n 1 | awk '{print $3}')
  echo "${p:-0} ${f:-0}"
}

step "install dependencies"
scripts/install-deps.sh --tests || { echo "tests: 0 passed, 1 failed"; exit 1; }

step "build (RelWithDebInfo)"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTENDRIL_BUILD_BENCHMARKS=ON >/dev/null &&
  cmake --build build -j "$jobs" || { echo "tests: 0 passed, 1 failed"; exit 1; }

step "unit, integration and server tests (ctest)"
ctest --test-dir build --output-on-failure -j "$jobs" --timeout 600 2>&1 | tee build/ctest.log
status=${PIPESTATUS[0]}
read -r p f < <(ctest_counts build/ctest.log)
record ctest "$status" "$p" "$f"

step "API tests over real sockets (curl-style REST, @foxglove/ws-protocol)"
bash tests/api/run.sh build/server/tendrild 2>&1 | tee build/api.log
status=${PIPESTATUS[0]}
read -r p f < <(node_counts build/api.log)
record api "$status" "$p" "$f"

step "browser test (Playwright + chromium)"
bash tests/e2e/run.sh build/server/tendrild 2>&1 | tee build/e2e.log
status=${PIPESTATUS[0]}
read -r p f < <(node_counts build/e2e.log)
record e2e "$status" "$p" "$f"

if [ "$quick" = 0 ]; then
  step "sanitizers: unit and integration tests under ASan + UBSan"
  # Left out here, run in the release ctest above: long numeric reproductions that take minutes
  # unoptimised (the §4.10.2 channel experiment, about 45 000 simulated ticks with vessel contact, and
  # the Table 4.1 design optimisation). Their code runs under the sanitizers in the contact, plant,
  # planner and catheter-mode tests. (Building this tree at -O1 instead made it 1.8x slower to compile
  # and the whole suite too long for CI.)
  sanitizer_skip='^(ChannelTest\.|DesignOptimiser\.ReproducesTable41Ordering$)'
  cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=Debug -DTENDRIL_SANITIZE=ON -DTENDRIL_BUILD_BENCHMARKS=OFF \
    -DTENDRIL_CAN_VM_TESTS=OFF >/dev/null &&
    cmake --build build-asan -j "$jobs" &&
    ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 \
      ctest --test-dir build-asan --output-on-failure -j "$jobs" --timeout 900 -E "$sanitizer_skip" 2>&1 |
      tee build-asan/ctest.log
  status=${PIPESTATUS[0]}
  [ -f build-asan/ctest.log ] || status=1
  read -r p f < <(ctest_counts build-asan/ctest.log 2>/dev/null || echo "0 0")
  record sanitizers "$status" "$p" "$f"

  step "fuzzing (libFuzzer, bounded)"
  fuzz_targets=(fuzz_rest_body fuzz_ws_client_message fuzz_centerline_csv fuzz_stl fuzz_can_pdo fuzz_calibration_request)
  CC=clang CXX=clang++ cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTENDRIL_FUZZ=ON \
    -DTENDRIL_BUILD_TESTS=ON -DTENDRIL_BUILD_BENCHMARKS=OFF -DTENDRIL_CAN_VM_TESTS=OFF >/dev/null &&
    cmake --build build-fuzz -j "$jobs" --target "${fuzz_targets[@]}"
  status=$?
  if [ $status -eq 0 ]; then
    fuzz_seconds=${TENDRIL_FUZZ_SECONDS:-60}
    run_fuzz() {  # run_fuzz <target>: its log and exit status land in build-fuzz/
      local corpus_dir
      corpus_dir=$(mktemp -d)
      cp -r tests/fuzz/corpus/"$1"/. "$corpus_dir"/ 2>/dev/null || true
      build-fuzz/tests/fuzz/"$1" -max_total_time="$fuzz_seconds" -rss_limit_mb=2048 -print_final_stats=1 \
        "$corpus_dir" >build-fuzz/"$1".log 2>&1
      echo $? >build-fuzz/"$1".status
      rm -rf "$corpus_dir"
    }
    rm -f build-fuzz/*.status
    # One target per core at a time (each fuzzer is single-threaded).
    for target in "${fuzz_targets[@]}"; do
      while [ "$(jobs -rp | wc -l)" -ge "$jobs" ]; do wait -n; done
      run_fuzz "$target" &
    done
    wait
    for target in "${fuzz_targets[@]}"; do
      if [ "$(cat build-fuzz/$target.status 2>/dev/null)" = 0 ]; then
        echo "$target: no crash in $fuzz_seconds s ($(grep -Eo 'stat::number_of_executed_units: [0-9]+' build-fuzz/$target.log | awk '{print $2}') runs)"
        record "$target" 0 1 0
      else
        echo "$target: FAILED"; tail -n 40 build-fuzz/$target.log
        record "$target" 1 0 1
      fi
    done
  else
    record fuzz-build 1 0 1
  fi

  step "clang-format"
  mapfile -t sources < <(git ls-files '*.cpp' '*.hpp')
  if clang-format --dry-run -Werror "${sources[@]}"; then
    echo "clang-format: clean"; record clang-format 0 1 0
  else
    record clang-format 1 0 1
  fi

  step "clang-tidy"
  mapfile -t tidy_sources < <(git ls-files 'teleop/src/*.cpp' 'safety/src/*.cpp' 'drivers/*/src/*.cpp' 'server/src/*.cpp' 'server/src/**/*.cpp' \
    'calibration/src/*.cpp' 'drivers/sim/imaging/src/simulated_side_view_camera.cpp')
  if printf '%s\n' "${tidy_sources[@]}" | xargs -P "$jobs" -n 4 clang-tidy -p build --quiet 2>build/clang-tidy.log >build/clang-tidy.out; then
    echo "clang-tidy: clean (${#tidy_sources[@]} files)"; record clang-tidy 0 1 0
  else
    cat build/clang-tidy.out | head -n 80; record clang-tidy 1 0 1
  fi
fi

echo
if [ "${#failed_steps[@]}" -gt 0 ]; then echo "failed steps: ${failed_steps[*]}"; fi
echo "tests: $passed passed, $failed failed"
[ "$failed" -eq 0 ] && [ "${#failed_steps[@]}" -eq 0 ]
