#!/usr/bin/env bash
# API tests of the variable-diameter continuum robot (config/robots/mbcr_vd.json, kind mbcr_vd) next to
# the catheter in one tendrild, over REST and WebSocket, a server of its own.
# Usage: tests/api/mbcr/run.sh [tendrild]
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../server.sh"
run_extra_robot_suite mbcr_vd.json "$here" "${1:-}"
