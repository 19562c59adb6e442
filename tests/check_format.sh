#!/usr/bin/env bash
# Checks that the C++ and CUDA sources are formatted as .clang-format says (CONTRIBUTING.md, "Format").
#   tests/check_format.sh [SOURCE_DIR]          list the files clang-format would change; exit 1 if any
#   tests/check_format.sh --fix [SOURCE_DIR]    format them in place
# Uses clang-format 14 (Debian 12's), the version the tree was formatted with: other versions break lines
# differently, so without it the check is skipped (exit 77, CTest's skip code). Bullet's example sources vendored
# unmodified under bench/dropin_corpus/third_party/bullet3_examples/ keep Bullet's own format.
set -uo pipefail
fix=0
if [ "${1:-}" = "--fix" ]; then fix=1; shift; fi
src="${1:-$(cd "$(dirname "$0")/.." && pwd)}"
cf=""
for c in clang-format-14 clang-format; do
  if command -v "$c" >/dev/null && "$c" --version | grep -q "version 14\."; then cf="$c"; break; fi
done
if [ -z "$cf" ]; then
  echo "clang-format 14 not found (Debian: apt-get install clang-format): format check skipped"
  exit 77
fi
cd "$src" || exit 2
if git rev-parse --is-inside-work-tree >/dev/null 2>&1; then
  mapfile -t files < <(git ls-files -- 'src/*' 'apps/*' 'tests/*' 'bench/*' 'demos/*' | grep -E '\.(h|hpp|cpp|cu|cuh)$' |
    grep -v '^bench/dropin_corpus/third_party/bullet3_examples/')
else
  mapfile -t files < <(find src apps tests bench demos -type f \( -name '*.h' -o -name '*.hpp' -o -name '*.cpp' -o -name '*.cu' -o -name '*.cuh' \) |
    grep -v '^bench/dropin_corpus/third_party/bullet3_examples/' | sort)
fi
if [ "$fix" = 1 ]; then
  "$cf" -i --style=file "${files[@]}"
  echo "formatted ${#files[@]} files"
  exit 0
fi
bad=()
for f in "${files[@]}"; do
  "$cf" --style=file --dry-run --Werror "$f" >/dev/null 2>&1 || bad+=("$f")
done
if [ ${#bad[@]} -gt 0 ]; then
  printf '%s: not formatted as .clang-format says\n' "${bad[@]}"
  echo "${#bad[@]} of ${#files[@]} files; fix with: tests/check_format.sh --fix"
  exit 1
fi
echo "format: all ${#files[@]} C++/CUDA sources as .clang-format says"
