#!/usr/bin/env bash
# Browser tests of the console: starts the given tendrild on a free port with a known token and the
# repo's config, runs tests/e2e/*.e2e.mjs in headless Chromium (playwright-core, no browser
# download: /usr/bin/chromium or $CHROMIUM), and always stops the server.
# console.e2e.mjs runs against a tendrild with the catheter in free space (see tests/api/server.sh);
# cockpit.e2e.mjs against a fresh one of the same kind; two_robots.e2e.mjs against one that adds the
# SIMULATED UR5 arm; mbcr.e2e.mjs against one that adds the SIMULATED mbcr_vd robot; tracking.e2e.mjs (the Tracking tab) against a fresh one; holds.e2e.mjs, which needs wall contact, against one that keeps the shipped
# SIMULATED vessel (TENDRIL_VESSEL_URL and TENDRIL_VESSEL_TOKEN point at it); replay.e2e.mjs against
# tendrild --replay on a few seconds another server recorded; surgeon.e2e.mjs (issue 31) against one
# with the catheter, the continuum robot and the arm. One server runs at a time: two sanitized
# servers with real-time threads beside a software-rendering Chromium starve the browser on two cores.
# Usage: tests/e2e/run.sh [path/to/tendrild] (default $TENDRILD, else build/server/tendrild).
# Screenshots: tests/e2e/artifacts/ (git-ignored).
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../api/server.sh"
trap stop_tendrild EXIT INT TERM

[ -d "$repo_root/node_modules/playwright-core" ] || { echo "run 'npm ci' in $repo_root first" >&2; exit 2; }
chromium_bin="${CHROMIUM:-/usr/bin/chromium}"
[ -x "$chromium_bin" ] || { echo "no Chromium at $chromium_bin (apt-get install chromium, or set CHROMIUM)" >&2; exit 2; }
binary="${1:-${TENDRILD:-$repo_root/build/server/tendrild}}"

status=0
run_file() {  # run_file <test file>: node's test runner over one file, the server log on failure
  node --test --test-concurrency=1 "$1"
  local s=$?
  if [ $s -ne 0 ]; then
    echo "--- last lines of the tendrild log ---" >&2
    tail -n 40 "$TENDRIL_LOG" >&2
    status=$s
  fi
}

start_tendrild "$binary" || exit 1
run_file "$here/console.e2e.mjs"
stop_tendrild

# The cockpit tests (cockpit.e2e.mjs) begin from a fresh server: nothing of the console tests' lease,
# e-stops or moves.
start_tendrild "$binary" || exit 1
run_file "$here/cockpit.e2e.mjs"
stop_tendrild

# Two robots in one server: the robot selector, and each robot's own lease.
TENDRIL_TEST_EXTRA_ROBOTS="$repo_root/config/robots/ur5_arm.json" start_tendrild "$binary" || exit 1
run_file "$here/two_robots.e2e.mjs"
stop_tendrild

# The variable-diameter robot's panel (mbcr.e2e.mjs): the catheter and the SIMULATED mbcr_vd robot.
TENDRIL_TEST_EXTRA_ROBOTS="$repo_root/config/robots/mbcr_vd.json" start_tendrild "$binary" || exit 1
run_file "$here/mbcr.e2e.mjs"
stop_tendrild

# The continuum robot's panel (continuum.e2e.mjs): the SIMULATED sdu_continuum beside the catheter.
TENDRIL_TEST_EXTRA_ROBOTS="$repo_root/config/robots/sdu_continuum.json" start_tendrild "$binary" || exit 1
run_file "$here/continuum.e2e.mjs"
stop_tendrild

# The ultrasound arm's panel (ultrasound.e2e.mjs): a sweep from the console while the catheter moves.
# The server's calibration store starts empty (server.sh): the test calibrates the arm from the
# console before the sweep.
# In simulated time (--simulated-time): a stall of this machine slips time and cannot fault or hold the arm.
TENDRIL_TEST_SIMULATED_TIME=1 TENDRIL_TEST_EXTRA_ROBOTS="$repo_root/config/robots/us_arm.json" start_tendrild "$binary" || exit 1
run_file "$here/ultrasound.e2e.mjs"
stop_tendrild

# The Tracking tab (tracking.e2e.mjs): tip tracking, segmentation editor and roadmaps, on a fresh server.
start_tendrild "$binary" || exit 1
run_file "$here/tracking.e2e.mjs"
# The 3D view's generic pieces (point clouds, SceneUpdate primitives, /tf frames) on the same server.
run_file "$here/scene_update.e2e.mjs"
# A live server's console asks no replay (replay_bar_live.e2e.mjs), on the same server.
run_file "$here/replay_bar_live.e2e.mjs"
stop_tendrild

# The replay bar (replay.e2e.mjs): a few seconds recorded by a live server (SIGTERM finalises them),
# then tendrild --replay on that recording.
TENDRIL_TEST_RECORDING=true start_tendrild "$binary" || exit 1
sleep 4
kill -TERM "$tendrild_pid" && wait "$tendrild_pid"
tendrild_pid=""
recorded_workdir="$tendrild_workdir"
tendrild_workdir=""  # kept while it is replayed
TENDRILD_ARGS="--config {config} --replay $TENDRIL_RECORDING_DIR" start_tendrild "$binary" || exit 1
run_file "$here/replay.e2e.mjs"
stop_tendrild
[ -n "${KEEP_TENDRILD_LOG:-}" ] || rm -rf "$recorded_workdir"

# Issue 31, the console as a surgeon drives it (surgeon.e2e.mjs): the catheter, the continuum robot and
# the arm in one server: refused mode switches and the layout from 1280 to 2560 px, goals typed before
# an E-STOP, degrees, switching robots (the stream stays live), per-robot tabs and 3D view.
TENDRIL_TEST_EXTRA_ROBOTS="$repo_root/config/robots/sdu_continuum.json $repo_root/config/robots/ur5_arm.json" \
  start_tendrild "$binary" || exit 1
run_file "$here/surgeon.e2e.mjs"
stop_tendrild

# Issue 31 item 13 (arm_calibrate.e2e.mjs): the ultrasound arm's Calibrate says why outside an ENABLED
# arm in cartesian mode; a fresh server with the arm, in simulated time as for ultrasound.e2e.mjs.
TENDRIL_TEST_SIMULATED_TIME=1 TENDRIL_TEST_EXTRA_ROBOTS="$repo_root/config/robots/us_arm.json" start_tendrild "$binary" || exit 1
run_file "$here/arm_calibrate.e2e.mjs"
stop_tendrild

# Issue 31 item 7 (tip_control.e2e.mjs): the Tip tab of the arm, the variable-diameter and the continuum
# robot (position, jog, Go, the arm's force), in simulated time as for the arm's other tests.
TENDRIL_TEST_SIMULATED_TIME=1 TENDRIL_TEST_EXTRA_ROBOTS="$repo_root/config/robots/ur5_arm.json $repo_root/config/robots/mbcr_vd.json $repo_root/config/robots/sdu_continuum.json" \
  start_tendrild "$binary" || exit 1
run_file "$here/tip_control.e2e.mjs"
stop_tendrild

TENDRIL_TEST_VESSEL=1 start_tendrild "$binary" || exit 1
export TENDRIL_VESSEL_URL="$TENDRIL_URL" TENDRIL_VESSEL_TOKEN="$TENDRIL_TOKEN" TENDRIL_VESSEL_LOG="$TENDRIL_LOG"
run_file "$here/holds.e2e.mjs"
exit $status
