"""Where the runs of an experiment live, and whether one is finished."""

from __future__ import annotations

import json
from pathlib import Path

from ham.errors import HamError

#: the most seeds a grid cell or a Table runs: far beyond any protocol (the paper's is 10), and
#: a count that cannot be listed (1e11) is refused before anything is written
MAX_SEEDS = 10_000


def check_seed_count(seeds) -> int:
    """``seeds`` (``--seeds N``: runs seeds 0..N-1) after checking it."""
    if not (isinstance(seeds, int) and not isinstance(seeds, bool) and 1 <= seeds <= MAX_SEEDS):
        raise HamError(f"seeds = {seeds!r}; accepted: an integer from 1 to {MAX_SEEDS}")
    return seeds


def run_dir(root: Path, key: str) -> Path:
    return Path(root) / "runs" / key


def read_metrics(out: Path) -> dict:
    """A run's metrics.json, or ``{}`` where it is missing or damaged (the run is then taken as
    unfinished: resuming it from its checkpoint writes the file again)."""
    try:
        d = json.loads((Path(out) / "metrics.json").read_text())
    except (OSError, ValueError):
        return {}
    return d if isinstance(d, dict) else {}


def _step(value) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def stopped_at(out: Path, metrics: dict | None = None) -> int | None:
    """The step a run stopped at with a perfect evaluation (``stopped_at_perfect``,
    :mod:`ham.learn.batched`), or None: it did not (or its metrics.json is damaged);
    ``metrics``: its metrics.json, if read already."""
    return _step((read_metrics(out) if metrics is None else metrics).get("stopped_at_perfect"))


def final_step(out: Path, steps: int, metrics: dict | None = None) -> int:
    """The step a run ends at: ``steps``, or the step it stopped at with a perfect evaluation
    (:func:`stopped_at`: its best accuracy cannot change); ``metrics``: its metrics.json, if
    read already."""
    stopped = stopped_at(out, metrics)
    return steps if stopped is None else min(steps, stopped)


def is_finished(out: Path, steps: int) -> bool:
    metrics = read_metrics(out)  # once: its steps, and the step it stopped at
    done = _step(metrics.get("steps"))
    return done is not None and done >= final_step(out, steps, metrics)


def evaluation_path(out: Path, spec: dict) -> Path:
    """Where the re-evaluation ``spec`` (policy, batches, seed) of a run's final checkpoint lives."""
    return Path(out) / f"eval_{spec['policy']}_{spec['batches']}b_seed{spec['seed']}.json"


def has_evaluation(out: Path, spec: dict, steps: int) -> bool:
    try:
        done = int(json.loads(evaluation_path(out, spec).read_text())["steps"])
        return done >= final_step(out, steps)
    except (OSError, ValueError, KeyError, TypeError):
        return False


def evaluate_final(out: Path, spec: dict) -> dict:
    """Re-evaluate a finished run's last checkpoint (as ``ham evaluate``) and keep the result."""
    from ham.learn.evaluation import evaluate
    from ham.learn.train import load_run
    from ham.world.files import write_json

    run = load_run(out)
    result = evaluate(run.agent, run.env, spec["batches"], seed=spec["seed"], policy=spec["policy"])
    d = {"steps": run.step, "eval_policy": spec["policy"], "seed": spec["seed"], **result.to_dict()}
    write_json(evaluation_path(out, spec), d, what="evaluation")
    return d


def per_object_accuracy(record: dict, objects: list) -> dict | None:
    """Per-object accuracy from an evaluation's confusion matrix (rows: the true object), if any."""
    import math

    import numpy as np

    confusion = record.get("confusion")
    try:
        c = np.asarray(confusion, dtype=float)
    except (TypeError, ValueError):
        return None
    if confusion is None or c.ndim != 2 or c.shape[0] != c.shape[1] or len(objects) != len(c):
        return None
    totals = c.sum(1)
    return {o: float(c[i, i] / totals[i]) if totals[i] else math.nan for i, o in enumerate(objects)}
