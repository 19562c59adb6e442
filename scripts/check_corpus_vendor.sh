#!/usr/bin/env bash
# Checks that Bullet's example files under bench/dropin_corpus/third_party/bullet3_examples/ are exactly Bullet's, byte
# for byte: each file's git blob hash against the blob at the commit its README names, in a clone or mirror of
# https://github.com/bulletphysics/bullet3.
#   scripts/check_corpus_vendor.sh BULLET3_GIT_DIR     exit 0 when every file matches, 1 otherwise, 2 bad usage
set -uo pipefail
commit=6c888f4abd7b46f572587360cc214985f02e5c6b
gitdir="${1:-}"
if [ -z "$gitdir" ] || ! git --git-dir="$gitdir" cat-file -e "$commit^{commit}" 2>/dev/null; then
  echo "usage: $0 BULLET3_GIT_DIR (a bullet3 clone's .git or a mirror holding commit $commit)" >&2
  exit 2
fi
cd "$(dirname "$0")/../bench/dropin_corpus/third_party/bullet3_examples" || exit 2
bad=0
n=0
while IFS= read -r f; do
  [ "$f" = README.md ] && continue
  n=$((n + 1))
  want=$(git --git-dir="$gitdir" rev-parse "$commit:$f" 2>/dev/null)
  have=$(git hash-object "$f")
  if [ "$want" != "$have" ]; then echo "$f: differs from bullet3 $commit" >&2; bad=1; fi
done < <(find . -type f | sed 's|^\./||' | sort)
[ "$bad" = 0 ] && echo "corpus: all $n files are bullet3 $commit's"
exit "$bad"
