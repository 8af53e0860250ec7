#!/usr/bin/env bash
# Image streaming benchmark (not a test: it reports numbers only). Starts tendrild with the simulated
# bi-plane fluoroscope at 1024×1024, 30 fps and joint states at 100 Hz, measures 4 Foxglove clients,
# then the same messages through a Node `ws` broadcast relay, and prints a table with the ratio.
#   tests/bench/image_stream_bench/run.sh [path/to/tendrild] [extra bench.mjs options, e.g. --duration 20]
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../../.." && pwd)"
tendrild="${1:-${TENDRILD:-$repo/build/server/tendrild}}"
[ $# -gt 0 ] && shift
[ -x "$tendrild" ] || { echo "image_stream_bench: '$tendrild' is not an executable tendrild (build it first)" >&2; exit 2; }
[ -d "$repo/node_modules/@foxglove/ws-protocol" ] || { echo "image_stream_bench: run 'npm ci' in $repo first" >&2; exit 2; }
exec node "$here/bench.mjs" --tendrild "$tendrild" "$@"
