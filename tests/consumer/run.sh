#!/usr/bin/env bash
# find_package(dvisim) from another project, both ways: from an installed copy (the built tree installed into a
# temporary prefix) and from the build tree itself; builds and runs tests/consumer against each. Also checks that
# the consumer's own sources include dvisim only through <dvisim/...> (compat.cpp: the deprecated paths) and that
# the installed headers are the list of src/CMakeLists.txt (public, compat, internal; tests/check_public_headers.py).
set -euo pipefail
build_dir=$1; src_dir=$2; work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
if grep -n '#include "' "$src_dir/tests/consumer/main.cpp"; then
  echo "tests/consumer/main.cpp: includes dvisim other than through <dvisim/...>"; exit 1
fi
cmake --install "$build_dir" --prefix "$work/prefix" > /dev/null
installed=$(cd "$work/prefix/include/dvisim" && find . -type f | sed 's|^\./||' | LC_ALL=C sort)
expected=$(python3 "$src_dir/tests/check_public_headers.py" --list "$src_dir" | LC_ALL=C sort)
if [ "$installed" != "$expected" ]; then
  echo "installed headers differ from src/CMakeLists.txt's lists:"; diff <(echo "$expected") <(echo "$installed") || true
  exit 1
fi
echo "installed headers: $(echo "$installed" | wc -l), as listed"
for way in installed build-tree; do
  if [ "$way" = installed ]; then prefix="$work/prefix"; else prefix="$build_dir"; fi
  cmake -S "$src_dir/tests/consumer" -B "$work/build-$way" -DCMAKE_PREFIX_PATH="$prefix" -DCMAKE_BUILD_TYPE=Release > /dev/null
  cmake --build "$work/build-$way" -j2 > /dev/null
  echo "find_package(dvisim) from the $way:"
  LD_LIBRARY_PATH="$work/prefix/lib:${LD_LIBRARY_PATH:-}" "$work/build-$way/consumer"
done
