#!/usr/bin/env bash
# API tests of the ultrasound arm (config/robots/us_arm.json, the serial_arm plug-in with its
# "ultrasound" section) beside the catheter in one tendrild, over REST and WebSocket: the sweep command,
# its refusals, a sweep begun while the catheter moves, /us_arm/sweep. A server of its own.
# Usage: tests/api/us_arm/run.sh [tendrild]
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../server.sh"
# The sweep needs calibrations (REQ-TF-7): the server starts with an empty store of its own
# (server.sh), so the suite calibrates first and leaves nothing behind.
run_extra_robot_suite us_arm.json "$here" "${1:-}"
