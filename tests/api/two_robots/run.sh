#!/usr/bin/env bash
# API tests of two robots in one server (the set-up of Heunis et al. 2021): the catheter and the UR5 arm
# (config/robots/ur5_arm.json) in one tendrild, over REST and WebSocket, a server of its own.
# Usage: tests/api/two_robots/run.sh [tendrild]
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../server.sh"
run_extra_robot_suite ur5_arm.json "$here" "${1:-}"
