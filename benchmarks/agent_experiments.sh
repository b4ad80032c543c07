#!/bin/bash
# Measurements for docs/agent.md; one core, sequential.
export OMP_NUM_THREADS=1
cd /work/main
H=".venv/bin/python -m ham"
$H train --glances 10 --steps 1500 --seed 0 --eval-every 100 --eval-batches 100 --threads 1 --no-progress --out runs/ham/g10_s0 > runs/ham/g10_s0.log 2>&1
for g in 3 2; do for pol in learned random; do for s in 0 1 2; do
  d=runs/ham/g${g}_${pol}_s${s}
  $H train --glances $g --policy $pol --steps 3000 --seed $s --eval-every 250 --eval-batches 50 --threads 1 --no-progress --out $d > $d.log 2>&1
done; done; done
echo done > runs/ham/ALL_DONE
