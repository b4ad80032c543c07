#!/usr/bin/env bash
# The batched trainer on a lent GPU in one device run (a few minutes): the GPU's name, the
# CUDA tests of tests/test_batched.py (CUDA batched runs equal single runs on the GPU, SGD and
# Adam; the step replayed as one CUDA graph equals the eager step, also from the command line)
# with the CPU ones beside them; then, not yet run on a GPU: bench_cuda_graph.py (the step
# replayed as one CUDA graph vs eager: speed, numbers, the grid's GPU-hours with it) and
# bench_merge_glances.py --device cuda (a Table 1 column's 2-10-glance runs as six models or as
# one, --merge-glances, docs/batched.md), with every step replayed as a graph and eager; then
# session 7's again: bench_batched.py --device cuda (steps, evaluations, the paper grid's
# projected GPU-hours, one group after another) and bench_side_by_side.py (1 and 15 groups
# sharing the GPU, as --executor batched --workers 15 runs them). The device machine's python3
# holds PyTorch with CUDA, h5py, TensorBoard, tqdm and pytest, which is all these need; ham runs
# from src/. From the device tool:
#   run(command="bash benchmarks/gpu_check.sh", timeout_s=600)
# Everything it prints also lands in $OUT/gpu_check.log. PYTHON=... picks another interpreter
# (on a machine without CUDA it runs the CPU tests and says it skipped the bench).
set -uo pipefail
PY=${PYTHON:-python3}
LOG=${OUT:-/tmp}/gpu_check.log
TABLE=${TMPDIR:-/tmp}/gpu_check_t201.h5
export PYTHONPATH=src PYTHONUNBUFFERED=1 MPLBACKEND=Agg
{
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null \
    || echo "no nvidia-smi"
  "$PY" -c "import torch; print('torch', torch.__version__, 'CUDA', torch.cuda.is_available())"
  "$PY" -m ham table build --grid 201 --out "$TABLE" >/dev/null && echo "table: $TABLE"
  "$PY" -m pytest -q -o addopts="" -p no:cacheprovider tests/test_batched.py -rs
  if "$PY" -c "import sys, torch; sys.exit(not torch.cuda.is_available())"; then
    # the new measurements first (a device run may be cut short), then session 7's again
    "$PY" benchmarks/bench_cuda_graph.py --device cuda --runs 10 --glances 3 10 --steps 30 \
      --table "$TABLE"
    "$PY" benchmarks/bench_merge_glances.py --device cuda --runs 10 --repeats 5 --table "$TABLE" \
      --cuda-graph
    "$PY" benchmarks/bench_merge_glances.py --device cuda --runs 10 --repeats 5 --table "$TABLE"
    "$PY" benchmarks/bench_batched.py --device cuda --runs 10 --glances 3 10 --repeats 5 \
      --table "$TABLE"
    "$PY" benchmarks/bench_side_by_side.py --device cuda --groups 1 15 --glances 3 10 \
      --steps 20 --table "$TABLE"
  else
    echo "no CUDA: bench_cuda_graph.py, bench_batched.py, bench_side_by_side.py and bench_merge_glances.py --device cuda skipped"
  fi
} 2>&1 | tee "$LOG"
