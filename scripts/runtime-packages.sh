#!/usr/bin/env bash
# Prints the Debian packages that hold the shared libraries a binary links directly (its NEEDED
# entries), one per line. docker/Dockerfile installs exactly these in the runtime image; apt brings
# their own dependencies. Usage: scripts/runtime-packages.sh <binary>
set -euo pipefail
binary="${1:?usage: runtime-packages.sh <binary>}"
needed="$(readelf -d "$binary" | sed -n 's/.*Shared library: \[\(.*\)\]/\1/p')"
resolved="$(ldd "$binary")"
for lib in $needed; do
  path="$(awk -v l="$lib" '$1 == l && $2 == "=>" {print $3}' <<< "$resolved")"
  [ -n "$path" ] || { echo "runtime-packages.sh: $lib (needed by $binary) is not found" >&2; exit 1; }
  # Debian 12 merges /lib into /usr/lib; dpkg knows each file under the path its package ships it at.
  pkg=""
  for candidate in "$path" "/usr$path" "${path#/usr}"; do
    pkg="$(dpkg -S "$candidate" 2>/dev/null | head -n 1 | cut -d: -f1)" && [ -n "$pkg" ] && break
  done
  [ -n "$pkg" ] || { echo "runtime-packages.sh: no Debian package holds $path" >&2; exit 1; }
  echo "$pkg"
done | sort -u
