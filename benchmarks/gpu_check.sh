#!/usr/bin/env bash
# The batched trainer on a lent GPU in one device run (about 6 minutes on an H100; 4.5 before
# the grid and sampled-evaluation parts were added): the GPU's name; first the measurements:
# bench_cuda_graph.py (the step replayed as one CUDA graph vs eager, groups together on their
# own streams, the grid's GPU-hours; a first and a later evaluation, with mean and with sampled
# poses), bench_merge_glances.py --device cuda replayed and eager (a Table 1 column's
# 2-10-glance runs as six models or one), and a 20-run grid from the command line with
# --cuda-graph, alone and with --groups-together 2 (timed; compare_grids.py compares their
# numbers). Then tests/test_batched.py (its CUDA tests with the CPU ones; PART_TESTS_S, default
# 240); then bench_batched.py --device cuda with a learned and a random first glance, and
# bench_side_by_side.py (1 and 15 eager groups sharing the GPU, as --workers 15 runs them).
# Results of 2026-12-05 (before the grid part): docs/batched.md, "On an H100". The device
# machine's python3 holds PyTorch with CUDA, h5py, TensorBoard, tqdm and pytest; it lacks
# Gymnasium, which ham's command line imports (the sb3 command's options), so its wheels travel
# in .whl (ignored by git; made here with `pip download --no-deps --only-binary=:all:
# --python-version 3.12 -d .whl gymnasium==1.4.0 farama-notifications==0.0.6`) and are installed
# under /tmp/site. ham runs from src/. Each part has its own time limit (PART_S seconds, default
# 150), so one that hangs leaves the rest their time. From the device tool:
#   run(command="bash benchmarks/gpu_check.sh", carry=[".whl"], timeout_s=600)
# Everything it prints also lands in $OUT/gpu_check.log. PYTHON=... picks another interpreter
# (on a machine without CUDA it runs the CPU tests and says it skipped the bench).
set -uo pipefail
PY=${PYTHON:-python3}
LOG=${OUT:-/tmp}/gpu_check.log
TABLE=${TMPDIR:-/tmp}/gpu_check_t201.h5
PART=${PART_S:-150}
export PYTHONPATH=src PYTHONUNBUFFERED=1 MPLBACKEND=Agg
part() { echo "== $*"; SECONDS=0; timeout "$PART" "$@"; echo "== rc $? in ${SECONDS}s"; }
{
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null \
    || echo "no nvidia-smi"
  if ! "$PY" -c "import gymnasium" 2>/dev/null && ls .whl/*.whl >/dev/null 2>&1; then
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site \
      .whl/*.whl && export PYTHONPATH=src:/tmp/site
  fi
  "$PY" -c "import torch; print('torch', torch.__version__, 'CUDA', torch.cuda.is_available())"
  "$PY" -m ham table build --grid 201 --out "$TABLE" >/dev/null && echo "table: $TABLE"
  if "$PY" -c "import sys, torch; sys.exit(not torch.cuda.is_available())"; then
    # the measurements never made on a GPU first (a device run may be cut short), then the
    # tests, then session 7's again on this card (its numbers were an H200's)
    part "$PY" benchmarks/bench_cuda_graph.py --device cuda --runs 10 --glances 3 10 --steps 30 \
      --table "$TABLE"
    # the evaluations with sampled poses (the paper-gazebo preset's), their draws kept
    part "$PY" benchmarks/bench_cuda_graph.py --device cuda --runs 10 --glances 3 10 --steps 10 \
      --together 0 --eval-policy sample --table "$TABLE"
    part "$PY" benchmarks/bench_merge_glances.py --device cuda --runs 10 --repeats 20 \
      --table "$TABLE" --cuda-graph
    part "$PY" benchmarks/bench_merge_glances.py --device cuda --runs 10 --repeats 20 \
      --table "$TABLE"
    # a grid end to end from the command line: 20 runs (two batched models) replayed, then the
    # same with both models stepped together on their own streams (--groups-together 2)
    GRID="reproduce table1 --profile quick --glances 3 10 --variants full --seeds 10 --steps 1000
      --executor batched --workers 1 --device cuda --cuda-graph --quiet"
    E2E=${TMPDIR:-/tmp}/gpu_check_e2e
    rm -rf "$E2E" && mkdir -p "$E2E"
    part "$PY" -m ham $GRID --out "$E2E/graph" >/dev/null
    part "$PY" -m ham $GRID --groups-together 2 --out "$E2E/together" >/dev/null
    part "$PY" benchmarks/compare_grids.py "$E2E/graph" "$E2E/together"
  fi
  PART=${PART_TESTS_S:-240} part "$PY" -m pytest -q -o addopts="" -p no:cacheprovider -n 4 \
    tests/test_batched.py -rs
  if "$PY" -c "import sys, torch; sys.exit(not torch.cuda.is_available())"; then
    part "$PY" benchmarks/bench_batched.py --device cuda --runs 10 --glances 3 10 --repeats 5 \
      --table "$TABLE" --first-glance learned
    part "$PY" benchmarks/bench_batched.py --device cuda --runs 10 --glances 3 10 --repeats 5 \
      --table "$TABLE"
    part "$PY" benchmarks/bench_side_by_side.py --device cuda --groups 1 15 --glances 3 10 \
      --steps 20 --table "$TABLE"
  else
    echo "no CUDA: the benches with --device cuda skipped"
  fi
} 2>&1 | tee "$LOG"
