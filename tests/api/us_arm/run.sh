#!/usr/bin/env bash
# API tests of the ultrasound arm (config/robots/us_arm.json, the serial_arm plug-in with its
# "ultrasound" section) beside the catheter in one tendrild, over REST and WebSocket: the sweep command,
# its refusals, a sweep begun while the catheter moves, /us_arm/sweep. A server of its own.
# Usage: tests/api/us_arm/run.sh [tendrild]
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../server.sh"
# The sweep needs a robot calibration (REQ-TF-7): a store of this run's own, so the suite starts
# without one and leaves none behind.
TENDRIL_STATE_DIR="$(mktemp -d /tmp/tendril-us-arm-api.XXXXXX)"
export TENDRIL_STATE_DIR
run_extra_robot_suite us_arm.json "$here" "${1:-}"
status=$?
rm -rf "$TENDRIL_STATE_DIR"
exit "$status"
