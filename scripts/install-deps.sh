#!/usr/bin/env bash
# Installs everything tendril needs on Debian 12: the build toolchain and libraries (apt), the
# console's packages and the test tools (npm, from package-lock.json). Idempotent; run as root or
# with sudo available. Shared by the README commands, CI (.ci/run) and docker/Dockerfile.
set -euo pipefail
cd "$(dirname "$0")/.."

with_tests=0
for arg in "$@"; do
  case "$arg" in
    --tests) with_tests=1 ;;
    *) echo "install-deps.sh: unknown option '$arg' (known: --tests)" >&2; exit 2 ;;
  esac
done

sudo_cmd=()
if [ "$(id -u)" != 0 ]; then
  command -v sudo >/dev/null || { echo "install-deps.sh: run as root or install sudo" >&2; exit 1; }
  sudo_cmd=(sudo)
fi

packages=(build-essential cmake ninja-build pkg-config git ca-certificates curl jq
  libboost-system-dev libboost-dev libeigen3-dev nlohmann-json3-dev libssl-dev openssl libopencv-dev)
# Node.js may come from Debian (nodejs + npm) or from a vendor package that bundles npm.
command -v node >/dev/null || packages+=(nodejs)
command -v npm >/dev/null || packages+=(npm)
if [ "$with_tests" = 1 ]; then
  packages+=(libgtest-dev libgmock-dev libbenchmark-dev clang clang-format clang-tidy libclang-rt-14-dev
    chromium qemu-system-x86 busybox-static iproute2 xz-utils cpio can-utils kmod)
fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
  echo "install-deps.sh: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  "${sudo_cmd[@]}" apt-get update -qq
  "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# The console's three.js and the test clients come from package-lock.json.
if [ -f package-lock.json ]; then
  if [ ! -d node_modules ] || [ package-lock.json -nt node_modules/.package-lock.json ]; then
    npm ci --no-audit --no-fund --loglevel=error
  fi
fi
