# The second device run (H100, 2026-12-05): the CUDA tests after the online-simulator fix, Adam's
# weights apart, and bench_cuda_graph.py with 8 and 15 groups together. From the device tool:
#   run(command="bash docs/results/gpu_h100/run2.sh", carry=[".whl"], timeout_s=420)
set -uo pipefail
export PYTHONPATH=src:/tmp/site PYTHONUNBUFFERED=1 MPLBACKEND=Agg
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl
{
  nvidia-smi --query-gpu=name --format=csv,noheader
  python3 -m ham table build --grid 201 --out /tmp/t201.h5 >/dev/null 2>&1 && echo table
  SECONDS=0; timeout 150 python3 -m pytest -q -o addopts="" -p no:cacheprovider -n 4 tests/test_batched.py -rs -k "cuda or graph or together" 2>&1 | tail -60; echo "== pytest ${SECONDS}s"
  SECONDS=0; timeout 150 python3 docs/results/gpu_h100/adam_apart.py; echo "== diag ${SECONDS}s"
  for k in 8 15; do SECONDS=0; timeout 120 python3 benchmarks/bench_cuda_graph.py --device cuda --runs 10 --glances 3 10 --steps 30 --together $k --table /tmp/t201.h5; echo "== bench ${SECONDS}s"; done
} 2>&1 | tee $OUT/run2.log
