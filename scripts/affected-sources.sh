#!/usr/bin/env bash
# Prints the C++ sources (repository-relative, one per line) that a change since <base> affects: the
# .cpp files changed since <base> (committed or not) and every source whose object file depends on a
# changed header, as the build's dependency log (ninja -t deps) records it.
# Without a usable <base> (empty, or not a commit of this history), every tracked .cpp file.
#   scripts/affected-sources.sh <base-commit> <build-dir>
set -euo pipefail
cd "$(dirname "$0")/.."
base=${1:-}
build=${2:-build}

if [ -z "$base" ] || ! git cat-file -e "$base^{commit}" 2>/dev/null || ! git merge-base --is-ancestor "$base" HEAD; then
  git ls-files '*.cpp'
  exit 0
fi
mapfile -t changed < <({ git diff --name-only "$base" -- '*.cpp' '*.hpp'; git ls-files --others --exclude-standard -- '*.cpp' '*.hpp'; } | sort -u)
[ "${#changed[@]}" -gt 0 ] || exit 0

{
  for f in "${changed[@]}"; do
    [[ "$f" == *.cpp ]] && [ -f "$f" ] && echo "$f"
  done
  headers=()
  for f in "${changed[@]}"; do [[ "$f" == *.hpp ]] && headers+=("$f"); done
  if [ "${#headers[@]}" -gt 0 ]; then
    # ninja -t deps: "<object>: #deps N ..." then one indented dependency per line. The object's source
    # is its one .cpp dependency (not the first one: with precompiled headers those come first).
    (cd "$build" && ninja -t deps) | awk -v root="$(pwd)/" -v list="$(printf '%s\n' "${headers[@]}")" '
      BEGIN { n = split(list, h, "\n"); for (i = 1; i <= n; i++) if (h[i] != "") want[h[i]] = 1 }
      function rel(p) { if (index(p, root) == 1) p = substr(p, length(root) + 1); sub(/^(\.\.\/)+/, "", p); return p }
      function flush() { if (hit && source != "") print source }
      /^[^ ]/ { flush(); source = ""; hit = 0; next }
      /^    / { p = rel(substr($0, 5)); if (p ~ /\.cpp$/ && source == "") source = p; else if (p in want) hit = 1 }
      END { flush() }'
  fi
} | sort -u
