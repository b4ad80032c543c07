"""``ham reproduce grid FILE``: run any grid of training runs (:mod:`ham.experiments.grid`) and report.

Runs go to ``DIR/runs/<cell>-s<seed>`` on the executors of ``ham reproduce`` (a local process
pool or Ray); a finished run is skipped, an interrupted one resumes, a failed one is retried and
then reported. Beside the runs: ``grid.json`` (the grid as read, re-runnable), ``plan.json``
(every run's resolved TrainConfig), ``results.json`` and ``report.md`` (best and final accuracy
per cell, mean ± standard error of the mean over seeds) and ``curves.png`` (accuracy during
training per cell, mean over seeds).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ham.errors import HamError, checked_arguments
from ham.experiments.executors import (
    BATCHED_EXECUTORS,
    EXECUTORS,
    BatchedOptions,
    check_batched_options,
    check_ray_address,
    execute,
    ray_session,
    unbatchable_note,
)
from ham.experiments.grid import Grid, GridJob, load_grid, settings_text
from ham.experiments.reproduce import format_mean_sem, mean_sem, spread_table
from ham.experiments.runs import (
    check_seed_count,
    evaluation_path,
    has_evaluation,
    is_finished,
    per_object_accuracy,
    read_metrics,
    run_dir,
)
from ham.world.devices import environment_record, source_commit
from ham.world.drawing import save_figure
from ham.world.files import check_output_dir, write_json, write_text

#: Keys of a run's config that may differ between invocations without making it another run.
_PLACE_KEYS = ("device", "table")


@checked_arguments
def run_grid(
    grid: Grid | str | os.PathLike,
    out: str | os.PathLike,
    *,
    seeds: int | None = None,
    executor: str = "local",
    workers: int | None = None,
    ray_address: str | None = None,
    device: str | None = None,
    retries: int = 1,
    progress: bool = True,
    command: str | None = None,
    batched: BatchedOptions | None = None,
    cache_dir: str | os.PathLike | None = None,
) -> dict:
    """Run what is not finished of ``grid`` (a :class:`Grid` or a grid file) into ``out``.

    ``seeds`` replaces every cell's seeds by ``0..seeds-1``; ``device`` sets every run's device.
    ``batched`` (:class:`ham.experiments.executors.BatchedOptions`) goes with
    ``executor="batched"`` and ``"ray-batched"``.
    ``cache_dir``: the table cache of a grid with ``[table] cache = true`` (default
    ``$HAM_CACHE_DIR`` or ``~/.cache/ham``). Returns the summary (``results.json`` plus ``ran``, ``skipped`` and ``failures``).
    """
    from ham.world.cache import cached_table
    from ham.world.config import WorldConfig
    from ham.world.files import folder_lock
    from ham.world.table import build_table

    if executor not in EXECUTORS:
        raise HamError(f"executor {executor!r}; accepted: {', '.join(EXECUTORS)}")
    source_commit()  # the code the grid starts with, named in results.json at the end
    batched = batched or BatchedOptions()
    check_batched_options(executor, batched)
    check_ray_address(executor, ray_address)
    if not isinstance(grid, Grid):
        grid = load_grid(grid)
    if seeds is not None:
        check_seed_count(seeds)
        cells = [{k: v for k, v in c.items() if k != "seeds"} for c in grid.cells]
        grid = replace(grid, seeds=seeds, cells=cells)
    if device is not None:
        grid = replace(grid, base={**grid.base, "device": device})
    if workers is not None and workers < 1:
        raise HamError(f"workers = {workers}; accepted: an integer >= 1 (default: all cores)")
    workers = workers or os.cpu_count() or 1
    if not (isinstance(retries, int) and retries >= 0):
        raise HamError(f"retries = {retries!r}; accepted: an integer >= 0")
    if cache_dir is not None and not grid.table_cache:
        raise HamError(
            f"--cache-dir {str(cache_dir)!r}: grid {grid.name!r} keeps no table in the cache; "
            "accepted: --cache-dir with a grid of [table] cache = true (docs/grids.md)"
        )
    root = check_output_dir(out).resolve()
    tables = grid.table_paths(root, cache_dir)
    jobs = grid.jobs(tables)
    check_batched_options(executor, batched, [j.config.get("device", "cpu") for j in jobs])
    note = unbatchable_note(jobs) if executor in BATCHED_EXECUTORS else None
    if note and progress:
        print(note, file=sys.stderr)
    _check_existing_runs(root, jobs)
    _check_sources(root, jobs)
    with ray_session(executor, ray_address, workers):  # before anything is written
        root.mkdir(parents=True, exist_ok=True)
        with folder_lock(root, what="--out"):  # the same --out run twice at once: refused
            for world, table in (tables or {}).items():  # one table per world, before any run
                if not Path(table).exists():
                    world = WorldConfig.from_dict(json.loads(world))
                    if grid.table_cache:
                        cached_table(world, grid.table_grid, cache_dir, progress=progress,
                                     command="ham reproduce grid")  # fmt: skip
                    else:
                        build_table(world, grid.table_grid, table, progress=progress,
                                    command="ham reproduce grid")  # fmt: skip
            write_json(root / "grid.json", grid.to_dict(), default=str)
            write_json(root / "plan.json", [j.to_dict() for j in jobs], default=str)

            todo = [j for j in jobs if not _complete(root, j)]
            results, failures = execute(
                jobs, todo, root, grid.world, grid.table_grid,
                executor=executor, workers=workers, ray_address=ray_address, retries=retries,
                progress=progress, desc=f"grid {grid.name}", batched=batched,
            )  # fmt: skip
    summary = write_report(
        root, grid, jobs, failures, command=command, executor=executor, note=note
    )
    summary["skipped"] = len(jobs) - len(todo)
    summary["ran"] = sum(r["status"] == "done" for r in results.values())
    return summary


def _complete(root: Path, job: GridJob) -> bool:
    out, steps = run_dir(root, job.key), job.config["steps"]
    return is_finished(out, steps) and all(has_evaluation(out, s, steps) for s in job.evaluate)


def _check_sources(root: Path, jobs: list[GridJob]) -> None:
    """Every run still to train that starts from another run (``init_from``) finds it: refused
    before anything is trained, not run by run."""
    from ham.learn.train import init_source_problem

    for job in jobs:
        source = job.config.get("init_from")
        problem = None if source is None else init_source_problem(source)
        if problem is not None and not _complete(root, job):  # a finished run needs it no more
            raise HamError(
                f"run {job.key} starts from init_from {source!r}, which {problem}; accepted: a "
                'folder of ham train for each seed ("{seed}" in init_from names the seed\'s run)'
            )


def _check_existing_runs(root: Path, jobs: list[GridJob]) -> None:
    """A run directory of the same key but another config is another experiment: stop."""
    for job in jobs:
        path = run_dir(root, job.key) / "config.json"
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(old, dict):  # damaged, as unreadable text: no config to compare
            continue
        old, new = _canonical(old), _canonical(job.config)
        for k in _PLACE_KEYS:
            old.pop(k, None)
            new.pop(k, None)
        if old != new:
            diff = _first_difference(old, new)
            raise HamError(
                f"{path.parent} holds a run with another config ({diff}); "
                "use another --out or remove that run"
            )


def _canonical(config: dict) -> dict:
    """A run's config as this version writes it: a field added since the run was written takes
    its default, as resume loads it (else every new option would make older runs "another
    config"); tuples become lists, as in the file. A config this version cannot load is kept."""
    from ham.learn.train import TrainConfig

    try:
        config = TrainConfig.from_dict(config).to_dict()
    except (HamError, TypeError, ValueError):
        pass
    return json.loads(json.dumps(config))


def _first_difference(old: dict, new: dict, prefix: str = "") -> str:
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            if a != b:
                return _first_difference(a, b, f"{prefix}{k}.")
        elif a != b:
            return f"{prefix}{k} {a!r} there, {b!r} in the grid"
    return "?"


# --------------------------------------------------------------------------- aggregate
def _stat(values) -> dict:
    m, s, n = mean_sem(values)
    return {"mean": m, "sem": s, "n": n}


def _mean_lists(lists: list) -> list[float] | None:
    lists = [x for x in lists if x]
    if not lists or len({len(x) for x in lists}) != 1:
        return None
    return [float(v) for v in np.mean(np.asarray(lists, dtype=float), axis=0)]


def aggregate(root: Path, grid: Grid, jobs: list[GridJob]) -> list[dict]:
    """Per cell: best/final accuracy and the re-evaluations, mean ± s.e.m. over finished seeds."""
    cells = []
    for cell in grid.expand():
        cjobs = [j for j in jobs if j.cell == cell.name]
        metrics, evals = [], {i: [] for i in range(len(grid.evaluate))}
        for j in cjobs:
            out = run_dir(root, j.key)
            if not is_finished(out, j.config["steps"]):
                continue
            metrics.append(read_metrics(out))
            for i, spec in enumerate(grid.evaluate):
                if has_evaluation(out, spec, j.config["steps"]):
                    evals[i].append(json.loads(evaluation_path(out, spec).read_text()))
        row = {
            "cell": cell.name,
            "settings": cell.settings,
            "labels": cell.labels,
            "seeds": list(cell.seeds),
            "runs": [j.key for j in cjobs],
            "finished": len(metrics),
            "steps": cjobs[0].config["steps"],
            "best_accuracy": _stat(m["best_accuracy"] for m in metrics),
            "final_accuracy": _stat(m["final_accuracy"] for m in metrics),
            "best_accumulated_accuracy": _stat(m["best_accumulated_accuracy"] for m in metrics),
            "accuracy_per_glance": _mean_lists([m.get("accuracy_per_glance") for m in metrics]),
            "pose_spread": _mean_lists([m.get("pose_spread") for m in metrics]),
            "pose_spread_within_object": _mean_lists(
                [m.get("pose_spread_within_object") for m in metrics]
            ),
            "evaluations": [
                {
                    **spec,
                    "accuracy": _stat(e["accuracy"] for e in evals[i]),
                    "accuracy_per_glance": _mean_lists(
                        [e["accuracy_per_glance"] for e in evals[i]]
                    ),
                }
                for i, spec in enumerate(grid.evaluate)
            ],
        }
        per_object = [
            p
            for m in metrics
            if m.get("history")
            and (p := per_object_accuracy(m["history"][-1], m.get("objects", []))) is not None
        ]
        if per_object and all(p.keys() == per_object[0].keys() for p in per_object):
            row["per_object_accuracy"] = {o: _stat(p[o] for p in per_object) for o in per_object[0]}
        cells.append(row)
    return cells


# --------------------------------------------------------------------------- report
def _entry(stat: dict) -> str:
    return format_mean_sem(stat["mean"], stat["sem"], stat["n"])


def results_markdown(grid: Grid, cells: list[dict]) -> str:
    """One row per cell: best and final accuracy (and re-evaluations), mean ± s.e.m. over seeds."""
    head = ["cell", "settings", "runs", "steps", "best accuracy (during training)",
            "final accuracy"]  # fmt: skip
    head += [f"final, {s['policy']} poses ({s['batches']} batches)" for s in grid.evaluate]
    last = grid.evaluate[-1] if grid.evaluate else None
    head.append(
        f"per glance (final, {last['policy']} poses)" if last else "per glance (last evaluation)"
    )
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in cells:
        per = c["evaluations"][-1]["accuracy_per_glance"] if last else c["accuracy_per_glance"]
        row = [
            f"`{c['cell']}`",
            settings_text(c["settings"]) or "base",
            f"{c['finished']}/{len(c['runs'])}",
            str(c["steps"]),
            _entry(c["best_accuracy"]),
            _entry(c["final_accuracy"]),
            *(_entry(e["accuracy"]) for e in c["evaluations"]),
            ", ".join(f"{a:.3f}" for a in per) if per else "—",
        ]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def pose_spread_markdown(cells: list[dict]) -> str | None:
    """Per cell: each glance's pose spread at the last evaluation during training, over all
    episodes and (in parentheses) within an object, mean over the finished seeds."""
    rows = [
        (f"`{c['cell']}`", c["pose_spread"], c["pose_spread_within_object"])
        for c in cells
        if c.get("pose_spread") and c.get("pose_spread_within_object")
    ]
    return spread_table(rows, first="cell") if rows else None


def per_object_markdown(cells: list[dict]) -> str | None:
    rows = [c for c in cells if "per_object_accuracy" in c]
    if not rows:
        return None
    objects = list(rows[0]["per_object_accuracy"])
    lines = ["| cell | " + " | ".join(objects) + " |", "|---|" + "---|" * len(objects)]
    for c in rows:
        po = c["per_object_accuracy"]
        lines.append(
            f"| `{c['cell']}` | " + " | ".join(_entry(po[o]) if o in po else "—" for o in objects)
            + " |"
        )  # fmt: skip
    return "\n".join(lines)


def draw_curves(root: Path, grid: Grid, jobs: list[GridJob], path: Path) -> Path | None:
    """Accuracy during training per cell: the mean over seeds, shaded ± s.e.m."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = []
    for cell in grid.expand():
        hs = []
        for j in jobs:
            if j.cell == cell.name:
                h = read_metrics(run_dir(root, j.key)).get("history", [])
                if h:
                    hs.append(h)
        if hs:
            n = min(len(h) for h in hs)
            steps = np.array([r["step"] for r in hs[0][:n]])
            acc = np.array([[r["accuracy"] for r in h[:n]] for h in hs])
            sem = acc.std(0, ddof=1) / math.sqrt(len(hs)) if len(hs) > 1 else None
            curves.append((cell.name, steps, acc.mean(0), sem))
    if not curves:
        return None
    fig, ax = plt.subplots(figsize=(7, 4.2))
    colors = plt.cm.tab10(np.arange(len(curves)) % 10)
    for (name, steps, mean, sem), color in zip(curves, colors, strict=True):
        ax.plot(steps, mean, color=color, label=name)
        if sem is not None:
            ax.fill_between(steps, mean - sem, mean + sem, color=color, alpha=0.2, lw=0)
    ax.set(xlabel="training step", ylabel="accuracy",
           title=f"Grid {grid.name}: accuracy during training (mean over seeds)")  # fmt: skip
    ax.legend(fontsize=7, loc="lower right")
    return save_figure(fig, path)


def write_report(
    root: Path,
    grid: Grid,
    jobs: list[GridJob],
    failures: list[dict],
    *,
    command: str | None,
    executor: str,
    note: str | None = None,
) -> dict:
    """``results.json``, ``report.md`` and ``curves.png`` from the finished runs; ``note``: a
    line on how the executor ran them (:func:`ham.experiments.executors.unbatchable_note`)."""
    cells = aggregate(root, grid, jobs)
    env = environment_record()
    summary = {"grid": grid.to_dict(), "cells": cells, "failures": failures, "environment": env}
    write_json(root / "results.json", summary, default=str)
    curves = draw_curves(root, grid, jobs, root / "curves.png")
    where = f"glance table {grid.table_grid} x {grid.table_grid}" if grid.table_grid else "online"
    lines = [
        f"# ham reproduce grid — `{grid.name}`",
        "",
        *([grid.description, ""] if grid.description else []),
        f"Command: `{command or 'ham reproduce grid ' + grid.name}`",
        f"Executor: {executor}. Written {time.strftime('%Y-%m-%d %H:%M:%S %Z')}."
        + (f" {note[0].upper()}{note[1:]}." if note else ""),
        "",
        f"{len(jobs)} run(s) in {len(cells)} cell(s); glances: {where}; world objects "
        f"`{grid.world.get('objects')}`. Every run (but where its cell's settings say "
        "otherwise): "
        + (settings_text(grid.base) or "the defaults")
        + ". Entries are mean ± standard error of the mean over the finished seeds "
        "(`runs` finished/planned); the grid is in `grid.json`, every run's config in "
        "`plan.json`.",
        "",
        "Environment: " + ", ".join(f"{k} {v}" for k, v in env.items()) + ".",
        "",
        "## Accuracy per cell",
        "",
        results_markdown(grid, cells),
        "",
    ]
    po = per_object_markdown(cells)
    if po:
        lines += ["## Accuracy per object (last evaluation during training)", "", po, ""]
    spread = pose_spread_markdown(cells)
    if spread:
        lines += ["## Pose spread per glance (last evaluation during training)", "", spread, ""]
    if curves is not None:
        lines += ["## Learning curves", "", f"![curves]({curves.name})", ""]
    if failures:
        lines += ["## Failed runs", ""]
        lines += [f"- `{f['key']}`: {f.get('error', '?')}" for f in failures]
        lines.append("")
    text = "\n".join(lines).rstrip("\n") + "\n"
    write_text(root / "report.md", text, what="report")
    return summary
