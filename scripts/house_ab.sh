#!/bin/bash
# Side-by-side bench scaling: the tree before the house restructuring (OLD) and this one (NEW), alternating.
set -u
OLD=/tmp/bo; NEW=/tmp/bd
if [ ! -x $NEW/bin/dvisim ]; then
  ( ln -sfn ../.deps .deps; cmake -S . -B $NEW -DCMAKE_CUDA_ARCHITECTURES=90 -DCMAKE_BUILD_TYPE=Release -DDVISIM_BUILD_DEMOS=OFF -DDVISIM_BUILD_TESTS=OFF > /tmp/bd_cfg.log 2>&1 && cmake --build $NEW -j8 --target dvisim_cli > /tmp/bd.log 2>&1 ) &
fi
( cd ../.snapold && ln -sfn ../.deps .deps && cmake -S . -B $OLD -DCMAKE_CUDA_ARCHITECTURES=90 -DCMAKE_BUILD_TYPE=Release -DDVISIM_BUILD_DEMOS=OFF -DDVISIM_BUILD_TESTS=OFF > /tmp/bo_cfg.log 2>&1 && cmake --build $OLD -j8 --target dvisim_cli > /tmp/bo.log 2>&1 ) || { tail -20 /tmp/bo.log; exit 1; }
wait
[ -x $NEW/bin/dvisim ] || { tail -20 /tmp/bd.log; exit 1; }
echo "old and new built"
for round in 1 2; do
  for v in new old; do
    B=$NEW; X="--stop-compare off"; [ $v = old ] && B=$OLD && X=""
    $B/bin/dvisim bench scaling --sizes 100k,1M --scenes pile --engines gpu,cpu --cpu-max 100000 --threads 16 $X --budget 8 --out /tmp/ab_${v}_$round > /tmp/ab_${v}_$round.log 2>&1
    echo "== $v round $round"; python3 -c "
import csv,sys
for r in csv.DictReader(open('/tmp/ab_${v}_$round/scaling.csv')): print(r['engine'], r['scene'], r['n'], r['ms_per_step'], r.get('iterations_mean', ''))
" || tail -5 /tmp/ab_${v}_$round.log
    mkdir -p $OUT/ab; cp /tmp/ab_${v}_$round/scaling.csv $OUT/ab/${v}_$round.csv 2>/dev/null
  done
done
