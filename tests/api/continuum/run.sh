#!/usr/bin/env bash
# API tests of the sensing-disk continuum robot (config/robots/sdu_continuum.json, kind sdu_continuum)
# beside the catheter in one tendrild, over REST and WebSocket, a server of its own (tests/api/server.sh
# run_extra_robot_suite). Usage: tests/api/continuum/run.sh [tendrild]
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
# shellcheck source=tests/api/server.sh
source "$here/../server.sh"
run_extra_robot_suite sdu_continuum.json "$here" "${1:-}"
