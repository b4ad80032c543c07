# The third device run (H100, 2026-12-05): the CUDA tests, then 20 runs of Table 1 (3 and 10
# glances, 10 seeds, 1,000 steps) with --cuda-graph and eager, timed, and their numbers compared.
#   run(command="bash docs/results/gpu_h100/run3.sh", carry=[".whl"], timeout_s=330)
set -uo pipefail
export PYTHONPATH=src:/tmp/site PYTHONUNBUFFERED=1 MPLBACKEND=Agg
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl
{
  nvidia-smi --query-gpu=name --format=csv,noheader
  SECONDS=0; timeout 120 python3 -m pytest -q -o addopts="" -p no:cacheprovider -n 4 tests/test_batched.py -rs -k "cuda" 2>&1 | tail -5; echo "== pytest ${SECONDS}s"
  G="reproduce table1 --profile quick --glances 3 10 --variants full --seeds 10 --steps 1000 --executor batched --workers 1 --device cuda --quiet"
  for mode in graph eager; do
    extra=""; [ $mode = graph ] && extra="--cuda-graph"
    SECONDS=0; timeout 110 python3 -m ham $G $extra --out /tmp/e2e-$mode > /tmp/e2e-$mode.log 2>&1; echo "== $mode rc $? in ${SECONDS}s"; tail -3 /tmp/e2e-$mode.log
  done
  python3 docs/results/gpu_h100/compare.py /tmp/e2e-eager /tmp/e2e-graph
} 2>&1 | tee $OUT/run3.log
