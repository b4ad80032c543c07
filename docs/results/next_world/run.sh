#!/usr/bin/env bash
# The learning grid of docs/results/next_world.md: curvature2d and composite:train, pose dims 2-4,
# 6 glances, 3 seeds; learned (info, hybrid) vs random locations; then every run re-evaluated
# (50 balanced batches), the composite runs also on the held-out instances composite:test.
# 54 runs of about 30-60 s each on one core (plus the 6 runs of the two ablations at the end).
set -euo pipefail
OUT=${OUT:-runs/next_world}
COMMON=(--glances 6 --height-input --optimizer adam --lr 0.003 --batch-size 16 --lr-step 100
        --lr-decay 0.6 --policy-lr-scale 0.3 --steps 300 --eval-every 150 --eval-batches 10
        --threads 1 --no-progress)
for objects in curvature2d composite:train; do
  for seed in 0 1 2; do
    for dims in x,y x,y,phi x,y,phi,phi_y; do
      name="${objects/:/-}_${dims//,/}"
      ham train --objects "$objects" --pose-dims "$dims" "${COMMON[@]}" --learner info \
        --seed "$seed" --out "$OUT/${name}_info_s$seed"
      ham train --objects "$objects" --pose-dims "$dims" "${COMMON[@]}" --learner info \
        --policy random --seed "$seed" --out "$OUT/${name}_random_s$seed"
      ham train --objects "$objects" --pose-dims "$dims" "${COMMON[@]}" --learner hybrid \
        --seed "$seed" --out "$OUT/${name}_hybrid_s$seed"
    done
  done
done
# ablations: no contact height; a random object pose per episode (yaw +-0.5 rad, offset +-1 cm)
for seed in 0 1 2; do
  ham train --objects curvature2d --pose-dims x,y,phi "${COMMON[@]}" --no-height-input \
    --learner info --seed "$seed" --out "$OUT/curvature2d_xyphi_infonoh_s$seed"
  ham train --objects composite:train --pose-dims x,y "${COMMON[@]}" --learner info \
    --object-yaw-max 0.5 --object-offset-max 0.01 --seed "$seed" \
    --out "$OUT/composite-train_xy_infopose_s$seed"
done
for run in "$OUT"/*/; do
  ham evaluate "$run" --batches 50 --seed 12345 --json > "$run/eval_train.json"
  case "$run" in
    */composite-train_*) ham evaluate "$run" --batches 50 --seed 12345 --objects composite:test \
                           --json > "$run/eval_test.json" ;;
  esac
done
# exact reference policies on 21 x 21 (x, y) tables (first glance random, as the HAM's)
for objects in curvature2d composite:train; do
  table="$OUT/${objects/:/-}_xy_21.h5"
  ham table build --objects "$objects" --pose-dims x,y --grid 21 --out "$table" --quiet
  for tolerance in 1e-6 0.05 0.2; do
    ham baselines --policy random --table "$table" --glances 1 2 3 4 5 6 --height \
      --tolerance "$tolerance"
    for policy in infogain oracle; do
      ham baselines --policy "$policy" --table "$table" --glances 1 2 3 4 5 6 --first random \
        --height --tolerance "$tolerance"
    done
  done
done
