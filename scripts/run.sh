#!/usr/bin/env bash
# Sets up and runs tendrild with the simulated SRMC catheter: installs what is missing, builds,
# and starts the server, which prints the console URL. Extra arguments go to tendrild
# (e.g. --listen 127.0.0.1:9090, --token T); see build/server/tendrild --help.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
# clang with lld (TENDRIL_USE_LLD) and precompiled headers (TENDRIL_PCH): the fastest way to a
# release tendrild on a fresh machine. An existing build-release keeps the compiler it was made with.
CC=clang CXX=clang++ cmake -S . -B build-release -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DTENDRIL_BUILD_TESTS=OFF -DTENDRIL_BUILD_BENCHMARKS=OFF >/dev/null
cmake --build build-release -j "$(nproc)" --target tendrild
exec build-release/server/tendrild --config config/server.json "$@"
