#!/usr/bin/env bash
# The curvature2d rows of run.sh (300 steps, 6 glances, pose dims 2-4, seeds 0-2) re-made with the
# shallow bowl, each run evaluated on 50 balanced batches. VARIANTS selects learners (default all).
set -uo pipefail
OUT=${OUT:-runs/next_world_c2d}; mkdir -p "$OUT"; cd "$OUT"
HAM=${HAM:-ham}
VARIANTS=${VARIANTS:-"info random hybrid"}
COMMON=(--glances 6 --height-input --optimizer adam --lr 0.003 --batch-size 16 --lr-step 100
        --lr-decay 0.6 --policy-lr-scale 0.3 --steps 300 --eval-every 150 --eval-batches 10
        --threads 1 --no-progress)
for v in $VARIANTS; do
  for seed in 0 1 2; do
    for dims in x,y x,y,phi x,y,phi,phi_y; do
      out=curvature2d_${dims//,/}_${v}_s$seed
      if ! { [ -f $out/metrics.json ] && grep -q '"steps": 300' $out/metrics.json; }; then
        case $v in
          info) extra=(--learner info);;
          random) extra=(--learner info --policy random);;
          hybrid) extra=(--learner hybrid);;
        esac
        /usr/bin/time -f "$out %e s wall %U s user" $HAM train --objects curvature2d \
          --pose-dims "$dims" "${COMMON[@]}" "${extra[@]}" --seed $seed --out $out
      fi
      [ -f $out/eval_train.json ] || $HAM evaluate $out --batches 50 --seed 12345 --json > $out/eval_train.json
    done
  done
done
echo ALLDONE
