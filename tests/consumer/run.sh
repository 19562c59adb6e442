#!/usr/bin/env bash
# find_package(dvisim) from another project, both ways: from an installed copy (the built tree installed into a
# temporary prefix) and from the build tree itself; builds and runs tests/consumer against each.
set -euo pipefail
build_dir=$1; src_dir=$2; work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cmake --install "$build_dir" --prefix "$work/prefix" > /dev/null
for way in installed build-tree; do
  if [ "$way" = installed ]; then prefix="$work/prefix"; else prefix="$build_dir"; fi
  cmake -S "$src_dir/tests/consumer" -B "$work/build-$way" -DCMAKE_PREFIX_PATH="$prefix" -DCMAKE_BUILD_TYPE=Release > /dev/null
  cmake --build "$work/build-$way" -j2 > /dev/null
  echo "find_package(dvisim) from the $way:"
  LD_LIBRARY_PATH="$work/prefix/lib:${LD_LIBRARY_PATH:-}" "$work/build-$way/consumer"
done
