#!/usr/bin/env bash
# Longer 4-D runs for #12: curvature2d, pose dims x,y,phi,phi_y, 6 glances, 3000 steps (10x the grid's), 3 seeds
set -uo pipefail
OUT=${OUT:-runs/next_world_4d}; mkdir -p "$OUT"; cd "$OUT"
HAM=${HAM:-ham}
COMMON=(--glances 6 --height-input --optimizer adam --lr 0.003 --batch-size 16 --lr-step 1000
        --lr-decay 0.6 --policy-lr-scale 0.3 --steps 3000 --eval-every 500 --eval-batches 10
        --threads 1 --no-progress)
for seed in 0 1 2; do
  for v in info random hybrid; do
    out=c2d_4d_${v}_s$seed
    [ -f $out/metrics.json ] && grep -q '"steps": 3000' $out/metrics.json && continue
    case $v in
      info) extra=(--learner info);;
      random) extra=(--learner info --policy random);;
      hybrid) extra=(--learner hybrid);;
    esac
    /usr/bin/time -f "$out %e s wall %U s user" $HAM train --objects curvature2d --pose-dims x,y,phi,phi_y "${COMMON[@]}" "${extra[@]}" --seed $seed --out $out
  done
done
for run in c2d_4d_*/; do
  $HAM evaluate "$run" --batches 50 --seed 12345 --json > "$run/eval_train.json"
done
echo ALLDONE
