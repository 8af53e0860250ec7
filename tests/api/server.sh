# Sourced by tests/api/run.sh and tests/e2e/run.sh: starts a tendrild binary on a free loopback port
# with a known token and the repo's config, waits for GET /api/v1/health, and kills it on exit.
# After `start_tendrild <binary>`: TENDRIL_URL, TENDRIL_TOKEN and TENDRIL_LOG are exported.
# The command line defaults to `tendrild --config <generated server.json>`; set TENDRILD_ARGS to
# replace the arguments after the binary ({config}, {port} and {token} are substituted).
# TENDRIL_TEST_SIMULATED_TIME=1 adds --simulated-time (tendrild --help): the logic runs in stepped time,
# and a stall of this machine slips simulated time instead of faulting or holding a robot.

repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
tendrild_pid=""
tendrild_workdir=""

stop_tendrild() {
  if [ -n "$tendrild_pid" ] && kill -0 "$tendrild_pid" 2>/dev/null; then
    kill -TERM "$tendrild_pid" 2>/dev/null || true
    for _ in $(seq 50); do
      kill -0 "$tendrild_pid" 2>/dev/null || break
      sleep 0.1
    done
    kill -KILL "$tendrild_pid" 2>/dev/null || true
    wait "$tendrild_pid" 2>/dev/null || true
  fi
  tendrild_pid=""
  if [ -n "$tendrild_workdir" ] && [ -z "${KEEP_TENDRILD_LOG:-}" ]; then rm -rf "$tendrild_workdir"; fi
}

free_port() {
  node -e 'const s=require("net").createServer();s.listen(0,"127.0.0.1",()=>{console.log(s.address().port);s.close();});'
}

start_tendrild() {
  local binary="$1"
  if [ -z "$binary" ] || [ ! -x "$binary" ]; then
    echo "usage: $0 <path to tendrild>   ('$binary' is not an executable file)" >&2
    return 2
  fi
  binary="$(cd "$(dirname "$binary")" && pwd)/$(basename "$binary")"
  tendrild_workdir="$(mktemp -d /tmp/tendril-test.XXXXXX)"
  local port token
  port="$(free_port)"
  token="test-$(od -An -N12 -tx1 /dev/urandom | tr -d ' \n')"
  # Same settings as config/server.json, with absolute paths, our port and token. Real-time priority
  # stays requested: on a busy machine it keeps the simulated drives' heartbeats on time (where it is
  # refused, tendrild logs that and runs without).
  # The robot file as shipped, but with the catheter in free space (the shipped SIMULATED vessel makes
  # any sizeable bend touch its wall, which would hold the robot in tests that are not about contact).
  # TENDRIL_TEST_VESSEL=1 keeps the vessel.
  node -e '
    const fs = require("fs");
    const robot = JSON.parse(fs.readFileSync(process.argv[1], "utf8"));
    if (process.argv[3] !== "1" && robot.catheter && robot.catheter.simulation) delete robot.catheter.simulation.vessel;
    fs.writeFileSync(process.argv[2], JSON.stringify(robot, null, 2));
  ' "$repo_root/config/robots/srmc.json" "$tendrild_workdir/srmc.json" "${TENDRIL_TEST_VESSEL:-0}"
  # TENDRIL_TEST_EXTRA_ROBOTS: more robot files (space-separated paths), served next to the catheter
  # (tests/api/two_robots/run.sh adds the arm).
  local extra_robots="" extra
  for extra in ${TENDRIL_TEST_EXTRA_ROBOTS:-}; do extra_robots+=", \"$extra\""; done
  cat > "$tendrild_workdir/server.json" <<JSON
{
  "listen": "127.0.0.1:$port",
  "token": "$token",
  "web_root": "$repo_root/web",
  "vendor_root": "$repo_root/node_modules",
  "control_rate_hz": 1000,
  "publish_rate_hz": 50,
  "realtime_priority": true,
  "robots": ["$tendrild_workdir/srmc.json"$extra_robots],
  "scene": {"vessel": "$repo_root/config/vessels/synthetic_ica.csv"},
  "imaging": {"enabled": true, "width": 512, "height": 512, "fps": 10, "jpeg_quality": 80,
              "sid_mm": 1000, "sod_mm": 750, "detector_mm": 160, "isocentre_mm": [15, -5, 55]},
  "recording": {"enabled": ${TENDRIL_TEST_RECORDING:-false}, "directory": "$tendrild_workdir/recordings",
                "max_file_mb": 8}
}
JSON
  export TENDRIL_RECORDING_DIR="$tendrild_workdir/recordings"
  local args=(--config "$tendrild_workdir/server.json")
  if [ -n "${TENDRILD_ARGS:-}" ]; then
    local expanded="${TENDRILD_ARGS//\{config\}/$tendrild_workdir/server.json}"
    expanded="${expanded//\{port\}/$port}"
    expanded="${expanded//\{token\}/$token}"
    read -r -a args <<< "$expanded"
  fi
  if [ "${TENDRIL_TEST_SIMULATED_TIME:-0}" = 1 ]; then args+=(--simulated-time); fi
  export TENDRIL_LOG="$tendrild_workdir/tendrild.log"
  # tendrild joins DDS by default (README, "DDS"): a test server's participant stays on loopback
  # unless the caller chose its own Cyclone DDS settings.
  export CYCLONEDDS_URI="${CYCLONEDDS_URI:-file://$repo_root/tests/dds/loopback.xml}"
  # TENDRIL_TOKEN in the environment would override the config's token (tendrild --help): a second
  # server started from this shell must not inherit the first one's.
  # Calibrations and other machine state (teleop/ultrasound_arm/README.md): each test server starts
  # with an empty store in its own work folder, never the user's ~/.local/state nor another server's.
  (cd "$repo_root" && TENDRIL_TOKEN="$token" TENDRIL_STATE_DIR="$tendrild_workdir/state" \
     exec "$binary" "${args[@]}") > "$TENDRIL_LOG" 2>&1 &
  tendrild_pid=$!
  export TENDRIL_PID="$tendrild_pid"
  export TENDRIL_URL="http://127.0.0.1:$port"
  export TENDRIL_TOKEN="$token"
  # Bounded by a count of tries; a server that died is reported at once with its log.
  for _ in $(seq 150); do
    if ! kill -0 "$tendrild_pid" 2>/dev/null; then
      echo "tendrild exited during start-up; its output:" >&2
      cat "$TENDRIL_LOG" >&2
      tendrild_pid=""
      return 1
    fi
    if node -e 'fetch(process.argv[1]).then(r=>process.exit(r.ok?0:1),()=>process.exit(1))' \
         "$TENDRIL_URL/api/v1/health" 2>/dev/null; then
      echo "tendrild up at $TENDRIL_URL (pid $tendrild_pid, log $TENDRIL_LOG)"
      return 0
    fi
    sleep 0.2
  done
  echo "tendrild did not answer /api/v1/health; its output:" >&2
  cat "$TENDRIL_LOG" >&2
  return 1
}

# Stops tendrild with SIGTERM and checks that it disabled its drives and exited 0 (the log line
# comes from tendrild after every drive reported its power stage off).
check_clean_shutdown() {
  [ -n "$tendrild_pid" ] || { echo "not ok - no tendrild to stop"; return 1; }
  kill -TERM "$tendrild_pid"
  local status=0
  wait "$tendrild_pid" || status=$?
  tendrild_pid=""
  if [ "$status" -eq 0 ] && grep -q "drives disabled, stopped cleanly" "$TENDRIL_LOG"; then
    echo "ok - SIGTERM: tendrild disabled the drives and exited 0"
    return 0
  fi
  echo "not ok - SIGTERM: exit status $status; log tail:"; tail -n 20 "$TENDRIL_LOG"
  return 1
}

# One suite of API tests against a server of its own that adds a robot file to the catheter (two
# robots in one tendrild), so the single-robot suite (tests/api/run.sh) keeps its timing: starts it,
# runs <suite dir>/*.test.mjs, then checks that SIGTERM disables every robot's drives and ends the
# process cleanly; the server's log tail on failure. Returns the suite's status.
# Usage: run_extra_robot_suite <robot file under config/robots> <suite dir> [tendrild]
run_extra_robot_suite() {
  local robot_file="$1" suite="$2" binary="${3:-${TENDRILD:-$repo_root/build/server/tendrild}}"
  trap stop_tendrild EXIT INT TERM
  [ -d "$repo_root/node_modules/@foxglove/ws-protocol" ] || { echo "run 'npm ci' in $repo_root first" >&2; return 2; }
  export TENDRIL_TEST_EXTRA_ROBOTS="$repo_root/config/robots/$robot_file"
  start_tendrild "$binary" || return 1
  node --test --test-concurrency=1 "$suite"/*.test.mjs
  local status=$?
  check_clean_shutdown || status=1
  if [ $status -ne 0 ]; then
    echo "--- last lines of the tendrild log ---" >&2
    tail -n 40 "$TENDRIL_LOG" >&2
  fi
  return $status
}
