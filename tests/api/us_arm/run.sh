#!/usr/bin/env bash
# API tests of the ultrasound arm (config/robots/us_arm.json, the serial_arm plug-in with its
# "ultrasound" section) beside the catheter in one tendrild, over REST and WebSocket: the sweep command,
# its refusals, a sweep begun while the catheter moves, /us_arm/sweep. A server of its own.
# Usage: tests/api/us_arm/run.sh [tendrild]
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../server.sh"
# The sweep needs calibrations: the server starts with an empty store of its own
# (server.sh), so the suite calibrates first and leaves nothing behind.
# In simulated time (tendrild --simulated-time): the logic runs stepped, and a stall of this shared
# machine slips simulated time instead of faulting or holding the moving arm, so any FAULT or hold here
# is a failure of the logic. The real-time behaviour has its own labelled test (ctest -L timing).
TENDRIL_TEST_SIMULATED_TIME=1 run_extra_robot_suite us_arm.json "$here" "${1:-}"
