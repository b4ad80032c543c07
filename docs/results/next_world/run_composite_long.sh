#!/usr/bin/env bash
# Longer composite runs for #12: composite:train, pose dims x,y ; x,y,phi ; x,y,phi,phi_y, 6 glances,
# 3000 steps (10x the grid's, the recipe of run_4d_long.sh), 3 seeds; learned (info) vs random
# locations (the same learner); each run evaluated on the training objects and on the held-out
# instances composite:test. DIMS, SEEDS and VARIANTS select a part (defaults: all); STEPS and LR_STEP
# stretch the budget (defaults 3000 and 1000; other budgets get a _STEPS suffix on the run folder);
# two copies may run side by side (a run being made by the other copy, $out.lock, is left to it).
set -uo pipefail
OUT=${OUT:-runs/next_world_composite}; mkdir -p "$OUT"; cd "$OUT"
HAM=${HAM:-ham}
DIMS=${DIMS:-"x,y x,y,phi x,y,phi,phi_y"}
VARIANTS=${VARIANTS:-"info random"}
SEEDS=${SEEDS:-"0 1 2"}
STEPS=${STEPS:-3000}
LR_STEP=${LR_STEP:-1000}
SUFFIX=""; [ "$STEPS" = 3000 ] || SUFFIX=_$STEPS
COMMON=(--glances 6 --height-input --optimizer adam --lr 0.003 --batch-size 16 --lr-step $LR_STEP
        --lr-decay 0.6 --policy-lr-scale 0.3 --steps $STEPS --eval-every 500 --eval-batches 10
        --threads 1 --no-progress)
for dims in $DIMS; do
  for seed in $SEEDS; do
    for v in $VARIANTS; do
      out=comp_${dims//,/}_${v}_s$seed$SUFFIX
      mkdir $out.lock 2>/dev/null || { echo "$out: left to the other copy ($out.lock)"; continue; }
      if ! { [ -f $out/metrics.json ] && grep -q "\"steps\": $STEPS" $out/metrics.json; }; then
        case $v in
          info) extra=(--learner info);;
          random) extra=(--learner info --policy random);;
          hybrid) extra=(--learner hybrid);;
        esac
        /usr/bin/time -f "$out %e s wall %U s user" $HAM train --objects composite:train \
          --pose-dims "$dims" "${COMMON[@]}" "${extra[@]}" --seed $seed --out $out
      fi
      [ -f $out/eval_train.json ] || $HAM evaluate $out --batches 50 --seed 12345 --json > $out/eval_train.json
      [ -f $out/eval_test.json ] || $HAM evaluate $out --batches 50 --seed 12345 \
        --objects composite:test --json > $out/eval_test.json
      rmdir $out.lock
    done
  done
done
echo ALLDONE
