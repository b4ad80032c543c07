#!/usr/bin/env bash
# The next world's transfer (docs/results/transfer.md, "The next world"): composite:train with
# poses x,y (12 objects that vary in x and y), 6 glances, the information learner with the contact
# height, 3,000 steps on the fast simulator's online glances (next_world/run_composite_long.sh's
# recipe), 3 seeds. Each run is evaluated on 21 x 21 (x, y) tables of the fast simulator, MuJoCo's
# taxels and MuJoCo's Gazebo read-out (ham evaluate --transfer-table). Then a few recorded glances:
# MuJoCo-Gazebo on a 5 x 5 grid (25 glances per object) exported as a .npz and imported with
# `ham table import-recorded --pose-dims x,y`; the fast runs fine-tuned on it (--init-from) and runs
# from scratch on it, 500 steps, each scored on the full 21 x 21 MuJoCo-Gazebo table; and, as the
# reference, runs trained 3,000 steps on that full table.
set -euo pipefail
OUT=${OUT:-runs/transfer_next_world}; mkdir -p "$OUT"; cd "$OUT"
HAM=${HAM:-ham}; PY=${PY:-python}
W=(--objects composite:train --pose-dims x,y)
for t in "fast taxels" "mujoco taxels" "mujoco gazebo"; do
  set -- $t
  [ -f "$1-$2-21.h5" ] || $HAM table build "${W[@]}" --grid 21 --simulator "$1" --sensor "$2" \
    --out "$1-$2-21.h5" --quiet
done
[ -f mujoco-gazebo-5.h5 ] || $HAM table build "${W[@]}" --grid 5 --simulator mujoco --sensor gazebo \
  --out mujoco-gazebo-5.h5 --quiet
# the 5 x 5 table's glances as a recorder would hand them over: one (5, 5, 16, 16) array per object
$PY - <<'PY'
import numpy as np
from ham.world.table import GlanceTable
t = GlanceTable.load("mujoco-gazebo-5.h5")
np.savez("recorded-5.npz", **{n: t.pressure[i].numpy() for i, n in enumerate(t.objects)},
         **{f"{n}.height": t.height[i].numpy() for i, n in enumerate(t.objects)})
PY
[ -f recorded-5.h5 ] || $HAM table import-recorded recorded-5.npz --pose-dims x,y --out recorded-5.h5
COMMON=(--glances 6 --height-input --optimizer adam --lr 0.003 --batch-size 16 --lr-step 1000
        --lr-decay 0.6 --policy-lr-scale 0.3 --eval-every 250 --eval-batches 10 --learner info
        --threads 1 --no-progress)
train() {  # train OUT ARGS...: a finished run is kept
  local out=$1; shift
  [ -f "$out/metrics.json" ] || $HAM train "$@" --out "$out" > "$out.log" 2>&1
}
for seed in 0 1 2; do
  train fast-s$seed "${W[@]}" "${COMMON[@]}" --steps 3000 --seed $seed &
  [ $seed = 1 ] && wait
done
wait
# at home on the target: the full 21 x 21 MuJoCo-Gazebo table, 3,000 steps
for seed in 0 1 2; do
  train home-s$seed --table mujoco-gazebo-21.h5 "${COMMON[@]}" --steps 3000 --seed $seed &
  [ $seed = 1 ] && wait
done
wait
for seed in 0 1 2; do
  train ft-s$seed --table recorded-5.h5 --init-from fast-s$seed "${COMMON[@]}" --steps 500 \
    --seed $seed &
  train scratch-s$seed --table recorded-5.h5 "${COMMON[@]}" --steps 500 --seed $seed
  wait
done
for run in fast-s? home-s? ft-s? scratch-s?; do
  for t in fast-taxels-21 mujoco-taxels-21 mujoco-gazebo-21; do
    [ -f "$run/eval_$t.json" ] || $HAM evaluate "$run" --transfer-table "$t.h5" --batches 50 \
      --seed 12345 --json > "$run/eval_$t.json"
  done
done
