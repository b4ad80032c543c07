"""Reproduce the paper's results: Table 1, Table 2 and the figures (section "Results").

``ham reproduce {table1,table2,figures,all} --profile {smoke,quick,paper} --out DIR`` plans a grid
of training runs, runs what is not finished yet (:mod:`ham.experiments.executors`: locally on a
process pool, as Ray tasks, or batched), and writes Markdown + JSON tables with the paper's
numbers beside ours, figures, and ``DIR/report.md``.

* Table 1: variants full model (``pi_M``), random locations (``pi_rloc``), MLP core (``pi_MLP``)
  and averaged MLP (``<pi_MLP>``, the MLP runs scored on their averaged outputs) for 1, 2, 3, 4,
  6, 8 and 10 glances.
* Table 2: the four what & where combiners at 3 glances.
* Each entry is the best accuracy within a run, averaged over seeds: mean +- standard error of
  the mean, as in the paper ("each experiment is repeated 10 times").

Runs live in ``DIR/runs/<key>``; a finished run is skipped, an interrupted one resumes from its
checkpoint, a failed one is retried and, if it fails again, reported (never silently dropped).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ham.errors import HamError, checked_arguments
from ham.experiments.executors import (
    EXECUTORS,
    BatchedOptions,
    check_batched_options,
    check_ray_address,
    execute,
    ray_session,
)
from ham.experiments.runs import (
    check_seed_count,
    is_finished,
    per_object_accuracy,
    read_metrics,
    run_dir,
    stopped_at,
)
from ham.world.devices import environment_record, source_commit
from ham.world.files import write_json, write_text

if TYPE_CHECKING:
    from ham.world.config import WorldConfig

TARGETS = ("table1", "table2", "figures", "all")

#: Table 1 of the paper: best accuracy within 50k steps, mean +- s.e.m. over 10 runs.
PAPER_TABLE1 = {
    "full": {1: (0.547, 0.002), 2: (0.831, 0.002), 3: (0.910, 0.001), 4: (0.942, 0.001),
             6: (0.977, 0.001), 8: (0.988, 0.001), 10: (0.994, 0.001)},
    "rloc": {1: (0.547, 0.002), 2: (0.753, 0.002), 3: (0.858, 0.001), 4: (0.917, 0.001),
             6: (0.971, 0.001), 8: (0.990, 0.000), 10: (0.995, 0.000)},
    "mlp": {1: (0.570, 0.003), 2: (0.668, 0.003), 3: (0.662, 0.003), 4: (0.662, 0.003),
            6: (0.670, 0.004), 8: (0.668, 0.004), 10: (0.668, 0.003)},
    "avg_mlp": {1: (0.570, 0.003), 2: (0.645, 0.003), 3: (0.829, 0.002), 4: (0.912, 0.002),
                6: (0.976, 0.001), 8: (0.993, 0.000), 10: (0.997, 0.000)},
}  # fmt: skip
#: Table 2 of the paper: 3 glances, best accuracy per what & where combiner.
PAPER_TABLE2 = {
    "mul": (0.873, 0.002),
    "concat1": (0.899, 0.002),
    "add": (0.902, 0.001),
    "concat2": (0.905, 0.001),
}
VARIANT_NAMES = {
    "full": "full model (pi_M)",
    "rloc": "random locations (pi_rloc)",
    "mlp": "MLP core (pi_MLP)",
    "avg_mlp": "averaged MLP (<pi_MLP>)",
}
COMBINER_NAMES = {
    "mul": "elem. multiplication",
    "concat1": "concat. followed by 1 layer",
    "add": "elem. addition",
    "concat2": "concat. followed by 2 layers",
}
#: The trained variants: the averaged MLP is the MLP runs scored on their averaged outputs.
TRAINED_VARIANTS = {"full": {}, "rloc": {"policy": "random"}, "mlp": {"core": "mlp"}}
GLANCES = (1, 2, 3, 4, 6, 8, 10)


@dataclass(frozen=True)
class Profile:
    """How much of the paper's protocol to run."""

    name: str
    steps: int
    seeds: int
    eval_every: int
    eval_batches: int
    heatmap_batches: int
    glances: tuple[int, ...] = GLANCES
    table_grid: int = 201
    #: Trained variants of Table 1 and the figures (``avg_mlp`` is scored on the ``mlp`` runs).
    variants: tuple[str, ...] = tuple(TRAINED_VARIANTS)

    def reductions(self) -> str:
        paper = PROFILES["paper"]
        if self == paper:
            return "none: the paper's protocol"
        parts = []
        for key in (
            "steps",
            "seeds",
            "eval_every",
            "eval_batches",
            "heatmap_batches",
            "table_grid",
        ):
            a, b = getattr(self, key), getattr(paper, key)
            if a != b:
                parts.append(f"{key} {a} (paper {b})")
        if self.glances != paper.glances:
            parts.append(f"glances {list(self.glances)} (paper {list(paper.glances)})")
        if self.variants != paper.variants:
            parts.append(f"variants {list(self.variants)} (paper {list(paper.variants)})")
        return "; ".join(parts)

    def subset(self, glances=None, variants=None) -> Profile:
        """This profile with Table 1 and the figures cut to some glance counts and variants."""
        out = self
        if glances is not None:
            g = tuple(glances)
            if not g or not all(
                isinstance(n, int) and not isinstance(n, bool) and 1 <= n <= 100 for n in g
            ):
                raise HamError(f"glances = {list(g)}; accepted: one or more integers in 1..100")
            out = replace(out, glances=tuple(sorted(set(g))))
        if variants is not None:
            v = tuple(variants)
            bad = [x for x in v if x not in TRAINED_VARIANTS]
            if not v or bad:
                raise HamError(
                    f"variants = {list(v)}; accepted: one or more of {', '.join(TRAINED_VARIANTS)}"
                )
            out = replace(out, variants=tuple(x for x in TRAINED_VARIANTS if x in v))
        return out


PROFILES = {
    "smoke": Profile("smoke", steps=12, seeds=1, eval_every=6, eval_batches=2, heatmap_batches=4,
                     glances=(1, 2, 3), table_grid=21),
    "quick": Profile("quick", steps=1000, seeds=2, eval_every=200, eval_batches=20,
                     heatmap_batches=100),
    "paper": Profile("paper", steps=50_000, seeds=10, eval_every=200, eval_batches=100,
                     heatmap_batches=1000),
}  # fmt: skip


@dataclass(frozen=True)
class Job:
    """One training run of the grid."""

    key: str
    variant: str
    combiner: str
    glances: int
    seed: int
    config: dict

    def to_dict(self) -> dict:
        return asdict(self)


# --------------------------------------------------------------------------- plan
#: The trained variants of Table 1 as a label axis of a grid (the overrides each stands for).
VARIANT_AXIS = [{"name": v, **{f"model.{k}": x for k, x in o.items()}}
                for v, o in TRAINED_VARIANTS.items()]  # fmt: skip
#: The paper's grids at the paper's protocol (docs/grids/table1.toml and table2.toml hold the
#: same): Table 1 is the variants x glances, Table 2 the combiners at 3 glances; the figures use
#: Table 1's full-model and random-location runs. A run is ``<variant>-<combiner>-g<G>-s<seed>``.
PAPER_GRIDS = {
    "table1": {
        "name": "table1",
        "description": "Table 1: best accuracy per number of glances and variant",
        "key": "{variant}-{model.combiner}-g{model.glances}",
        "seeds": 10,
        "table": {"grid": 201},
        "base": {"steps": 50_000, "eval_every": 200, "eval_batches": 100,
                 "model.combiner": "concat2"},
        "axes": {"variant": VARIANT_AXIS, "model.glances": list(GLANCES)},
    },
    "table2": {
        "name": "table2",
        "description": "Table 2: what & where combiners, 3 glances",
        "key": "{variant}-{model.combiner}-g{model.glances}",
        "seeds": 10,
        "table": {"grid": 201},
        "base": {"steps": 50_000, "eval_every": 200, "eval_batches": 100, "model.glances": 3},
        "axes": {"variant": VARIANT_AXIS[:1], "model.combiner": list(PAPER_TABLE2)},
    },
}  # fmt: skip


def paper_grid(
    name: str,
    profile: Profile,
    seeds: int | None = None,
    device: str = "cpu",
    world: dict | None = None,
    eval_policy: str | None = None,
):
    """Table 1 (``table1``, also the figures' runs: ``figures``) or Table 2 as a :class:`Grid`,
    cut to ``profile``'s protocol, glance counts and variants, in ``world`` (default: the paper's),
    evaluated with ``eval_policy`` (default: TrainConfig's).
    """
    from ham.experiments.grid import Grid

    d = json.loads(json.dumps(PAPER_GRIDS["table2" if name == "table2" else "table1"]))
    if world is not None:
        d["world"] = world
    d["seeds"] = profile.seeds if seeds is None else seeds
    d["table"] = {"grid": profile.table_grid}
    d["base"].update(steps=profile.steps, eval_every=profile.eval_every,
                     eval_batches=profile.eval_batches)  # fmt: skip
    if device != "cpu":
        d["base"]["device"] = device
    if eval_policy is not None:
        d["base"]["eval_policy"] = eval_policy
    if name != "table2":
        kept = [v for v in profile.variants if name == "table1" or v in ("full", "rloc")]
        d["axes"]["variant"] = [v for v in VARIANT_AXIS if v["name"] in kept]
        d["axes"]["model.glances"] = list(profile.glances)
    if name == "figures":
        d["name"], d["description"] = "figures", "the figures' runs"
    if not d["axes"]["variant"]:
        return None
    return Grid.from_dict(d)


def plan(
    target: str,
    profile: Profile,
    seeds: int,
    table: str,
    device: str = "cpu",
    world: dict | None = None,
    eval_policy: str | None = None,
) -> list[Job]:
    """The runs ``target`` needs, deduplicated (Table 2's concat2 run is Table 1's full model).

    ``world`` (a WorldConfig dict; default the paper's) is recorded in every run's config.
    """
    if target not in TARGETS:
        raise HamError(f"target {target!r}; accepted: {', '.join(TARGETS)}")
    names = {"table1": ["table1"], "table2": ["table2"], "figures": ["figures"],
             "all": ["table1", "table2", "figures"]}[target]  # fmt: skip
    jobs: dict[str, Job] = {}
    for name in names:
        grid = paper_grid(name, profile, seeds, device, world, eval_policy)
        for j in grid.jobs(table) if grid is not None else []:
            if j.key not in jobs:
                model = j.config["model"]
                jobs[j.key] = Job(j.key, j.labels["variant"], model["combiner"],
                                  model["glances"], j.seed, j.config)  # fmt: skip
    return list(jobs.values())


# --------------------------------------------------------------------------- aggregate
def mean_sem(values: Iterable[float]) -> tuple[float, float, int]:
    v = np.asarray(list(values), dtype=float)
    if v.size == 0:
        return math.nan, math.nan, 0
    sem = float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else math.nan
    return float(v.mean()), sem, int(v.size)


def format_mean_sem(mean: float, sem: float, n: int) -> str:
    """A table cell: ``0.946 ± 0.025``, ``(n=1)`` for one run, ``—`` for none."""
    if n == 0 or math.isnan(mean):
        return "—"
    if n == 1 or math.isnan(sem):
        return f"{mean:.3f} (n=1)"
    return f"{mean:.3f} ± {sem:.3f}"


def load_metrics(root: Path, jobs: list[Job]) -> dict[str, dict]:
    out = {}
    for job in jobs:
        m = read_metrics(run_dir(root, job.key))  # {}: none yet, or damaged
        if m:
            out[job.key] = m
    return out


def table1(root: Path, jobs: list[Job], profile: Profile) -> dict:
    metrics = load_metrics(root, jobs)
    rows = {}
    for g in profile.glances:
        row = {}
        for variant in ("full", "rloc", "mlp", "avg_mlp"):
            trained = "mlp" if variant == "avg_mlp" else variant
            field = "best_accumulated_accuracy" if variant == "avg_mlp" else "best_accuracy"
            keys = [
                j.key
                for j in jobs
                if j.variant == trained and j.combiner == "concat2" and j.glances == g
            ]
            vals = [metrics[k][field] for k in keys if k in metrics]
            m, s, n = mean_sem(vals)
            paper = PAPER_TABLE1[variant].get(g)
            row[variant] = {"mean": m, "sem": s, "n": n, "paper": paper}
        rows[g] = row
    return rows


def table2(root: Path, jobs: list[Job]) -> dict:
    metrics = load_metrics(root, jobs)
    rows = {}
    for c in PAPER_TABLE2:
        keys = [j.key for j in jobs if j.variant == "full" and j.combiner == c and j.glances == 3]
        m, s, n = mean_sem(metrics[k]["best_accuracy"] for k in keys if k in metrics)
        rows[c] = {"mean": m, "sem": s, "n": n, "paper": PAPER_TABLE2[c]}
    return rows


def table1_markdown(rows: dict) -> str:
    head = (
        "| glances | "
        + " | ".join(f"{VARIANT_NAMES[v]}: ours | paper" for v in PAPER_TABLE1)
        + " |"
    )
    sep = "|---|" + "---|---|" * len(PAPER_TABLE1)
    lines = [head, sep]
    for g, row in rows.items():
        cells = []
        for v in PAPER_TABLE1:
            r = row[v]
            paper = "—" if r["paper"] is None else f"{r['paper'][0]:.3f} ± {r['paper'][1]:.3f}"
            cells += [format_mean_sem(r["mean"], r["sem"], r["n"]), paper]
        lines.append(f"| {g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def table2_markdown(rows: dict) -> str:
    lines = ["| combiner | ours | paper |", "|---|---|---|"]
    for c, r in rows.items():
        paper = f"{r['paper'][0]:.3f} ± {r['paper'][1]:.3f}"
        lines.append(
            f"| {COMBINER_NAMES[c]} | {format_mean_sem(r['mean'], r['sem'], r['n'])} | {paper} |"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- the command
@checked_arguments
def reproduce(
    target: str,
    profile_name: str,
    out: str | os.PathLike,
    *,
    seeds: int | None = None,
    steps: int | None = None,
    executor: str = "local",
    workers: int | None = None,
    ray_address: str | None = None,
    device: str = "cpu",
    retries: int = 1,
    progress: bool = True,
    command: str | None = None,
    glances: Iterable[int] | None = None,
    variants: Iterable[str] | None = None,
    world: WorldConfig | None = None,
    batched: BatchedOptions | None = None,
    eval_policy: str | None = None,
    table_cache: bool = False,
    cache_dir: str | os.PathLike | None = None,
) -> dict:
    """Plan, run (skipping finished runs), aggregate and report. Returns the summary dict.

    ``glances`` and ``variants`` cut Table 1 and the figures to a part of the grid (Table 2 is
    always the four combiners at 3 glances), e.g. the paper's protocol for one row on a laptop.
    ``steps`` replaces the profile's training steps (its evaluation interval and batches stay;
    the report names the change), e.g. as many steps as a GPU lease holds.
    ``world``: the world of the glance table (default: the paper's); with an objects file, every
    worker registers the file's objects from the record in the table and the world.
    ``batched`` (:class:`BatchedOptions`) goes with ``executor="batched"`` and ``"ray-batched"``.
    ``eval_policy``: the evaluation during training (a world preset's; default TrainConfig's).
    ``table_cache``: take the glance table from the table cache (:mod:`ham.world.cache`, in
    ``cache_dir``), built there once, instead of ``OUT/table_<N>.h5`` (a preset's slow world).
    """
    from ham.learn.evaluation import EVAL_POLICIES
    from ham.model.agent import HamConfig
    from ham.world.cache import cached_table
    from ham.world.config import WorldConfig
    from ham.world.devices import check_device
    from ham.world.files import check_output_dir, folder_lock
    from ham.world.objects import resolve_set
    from ham.world.table import build_table

    source_commit()  # the code the reproduction starts with, named in summary.json at the end
    if target not in TARGETS:
        raise HamError(f"target {target!r}; accepted: {', '.join(TARGETS)}")
    if profile_name not in PROFILES:
        raise HamError(f"profile {profile_name!r}; accepted: {', '.join(PROFILES)}")
    if executor not in EXECUTORS:
        raise HamError(f"executor {executor!r}; accepted: {', '.join(EXECUTORS)}")
    if eval_policy is not None and eval_policy not in EVAL_POLICIES:  # before OUT is made
        raise HamError(f"eval_policy = {eval_policy!r}; accepted: {', '.join(EVAL_POLICIES)}")
    if cache_dir is not None and not table_cache:  # said, not silently ignored
        raise HamError(
            f"cache_dir = {str(cache_dir)!r} without table_cache; accepted: cache_dir with "
            "table_cache=True (the glance table from the cache)"
        )
    batched = batched or BatchedOptions()
    check_batched_options(executor, batched, [device])
    profile = PROFILES[profile_name]
    if seeds is not None:
        profile = replace(profile, seeds=check_seed_count(seeds))
    if steps is not None:
        if not (isinstance(steps, int) and not isinstance(steps, bool) and steps >= 1):
            raise HamError(f"steps = {steps!r}; accepted: an integer >= 1")
        profile = replace(profile, steps=steps)
    profile = profile.subset(glances, variants)
    if workers is not None and not (isinstance(workers, int) and workers >= 1):
        raise HamError(f"workers = {workers!r}; accepted: an integer >= 1 (default: all cores)")
    workers = workers or os.cpu_count() or 1
    check_ray_address(executor, ray_address)
    if not (isinstance(retries, int) and retries >= 0):
        raise HamError(f"retries = {retries!r}; accepted: an integer >= 0")
    check_device(device)
    root = check_output_dir(out).resolve()
    if world is None:
        world = WorldConfig()
    elif not isinstance(world, WorldConfig):  # a name only a type checker sees: checked here
        raise HamError(f"reproduce: world = {world!r}; accepted: a WorldConfig or None")
    # unknown objects, or too few to classify, are named before the folder is made
    HamConfig(n_objects=len(resolve_set(world.objects)))
    with ray_session(executor, ray_address, workers):  # before anything is written
        root.mkdir(parents=True, exist_ok=True)
        with folder_lock(root, what="--out"):  # the same --out run twice at once: refused
            table = root / f"table_{profile.table_grid}.h5"
            if table_cache:
                table = cached_table(world, profile.table_grid, cache_dir, progress=progress,
                                     command=command or "ham reproduce")  # fmt: skip
            elif table.exists():
                _check_table_objects(table, world)
            else:
                build_table(world, profile.table_grid, table, progress=progress,
                            command=command or "ham reproduce")  # fmt: skip
            jobs = plan(target, profile, profile.seeds, str(table), device, world.to_dict(),
                        eval_policy)  # fmt: skip
            write_json(root / "plan.json", [j.to_dict() for j in jobs])

            todo = [j for j in jobs if not is_finished(run_dir(root, j.key), profile.steps)]
            results, failures = execute(
                jobs, todo, root, world.to_dict(), profile.table_grid,
                executor=executor, workers=workers, ray_address=ray_address, retries=retries,
                progress=progress, desc=f"reproduce {target} ({profile.name})", batched=batched,
            )  # fmt: skip
    skipped = len(jobs) - len(todo)
    summary = write_outputs(
        root, target, profile, jobs, failures, command=command, executor=executor
    )
    summary["skipped"] = skipped
    summary["ran"] = sum(r["status"] == "done" for r in results.values())
    return summary


def _check_table_objects(table: Path, world: WorldConfig) -> None:
    """Refuse to reuse ``OUT``'s table when it was built for other objects than ``world``'s."""
    from ham.world.table import table_info

    built = table_info(table).world
    rec = built.get("objects_file")
    if (built.get("objects"), rec) != (world.objects, world.objects_file):
        name = f" from {rec['name']}" if rec else ""
        raise HamError(
            f"{table} holds glances of objects {built.get('objects')!r}{name}, not "
            f"{world.objects!r}; use another --out (or the same objects and objects file)"
        )


def write_outputs(
    root: Path,
    target: str,
    profile: Profile,
    jobs: list[Job],
    failures: list[dict],
    *,
    command: str | None,
    executor: str,
) -> dict:
    """Tables (Markdown + JSON), figures (PNG) and ``report.md`` from the finished runs."""
    from ham.experiments.reproduce_figures import draw_figures

    summary: dict = {"target": target, "profile": asdict(profile), "failures": failures}
    sections = []
    if target in ("table1", "all"):
        t1 = table1(root, jobs, profile)
        md = table1_markdown(t1)
        write_text(root / "table1.md", md + "\n")
        write_json(root / "table1.json", {str(k): v for k, v in t1.items()}, default=str)
        summary["table1"] = t1
        sections.append(("Table 1: best accuracy per number of glances", md))
    if target in ("table2", "all"):
        t2 = table2(root, jobs)
        md = table2_markdown(t2)
        write_text(root / "table2.md", md + "\n")
        write_json(root / "table2.json", t2, default=str)
        summary["table2"] = t2
        sections.append(("Table 2: what & where combiners, 3 glances", md))
    per_object = per_object_markdown(root, jobs)
    if per_object:
        sections.append(("Accuracy per object (last evaluation, mean over seeds)", per_object))
    spread = pose_spread_markdown(root, jobs)
    if spread:
        sections.append(("Pose spread per glance (last evaluation, mean over seeds)", spread))
    figures = []
    if target in ("figures", "all"):
        figures = draw_figures(root, jobs, profile)
    summary["figures"] = [str(Path(f).relative_to(root)) for f in figures]
    summary["stopped_at_perfect"] = stopped_at_perfect(root, jobs)
    summary["environment"] = environment_record()
    write_json(root / "summary.json", summary, default=str)
    report = render_report(
        target, profile, sections, summary["figures"], failures, command, executor,
        stopped=summary["stopped_at_perfect"], steps=profile.steps, env=summary["environment"],
    )  # fmt: skip
    write_text(root / "report.md", report, what="report")
    return summary


def stopped_at_perfect(root: Path, jobs: list[Job]) -> dict[str, int]:
    """The runs that ``--stop-at-perfect`` stopped: run key -> the step of their perfect
    evaluation (their curves end there)."""
    steps = {j.key: stopped_at(run_dir(root, j.key)) for j in jobs}
    return {k: s for k, s in steps.items() if s is not None}


def per_object_markdown(root: Path, jobs: list[Job]) -> str | None:
    """Per run group (variant, combiner, glances): each object's accuracy after the last glance
    at the last evaluation (its confusion matrix), mean over the finished seeds."""
    groups: dict[tuple, list[dict]] = {}
    objects: list[str] | None = None
    for j in jobs:
        m = read_metrics(run_dir(root, j.key))
        if not m.get("history"):
            continue
        acc = per_object_accuracy(m["history"][-1], m.get("objects", []))
        if acc is None:
            continue
        objects = objects or list(acc)
        groups.setdefault((j.variant, j.combiner, j.glances), []).append(acc)
    if not groups or objects is None:
        return None
    lines = ["| run | glances | " + " | ".join(objects) + " |",
             "|---|---|" + "---|" * len(objects)]  # fmt: skip
    for (variant, combiner, glances), accs in sorted(
        groups.items(), key=lambda kv: (kv[0][2], kv[0][0], kv[0][1])
    ):
        cells = []
        for o in objects:
            vals = [a[o] for a in accs if o in a and not math.isnan(a[o])]
            cells.append(f"{sum(vals) / len(vals):.3f}" if vals else "—")
        lines.append(
            f"| {variant}-{combiner} ({len(accs)} seed(s)) | {glances} | "
            + " | ".join(cells)
            + " |"
        )
    return "\n".join(lines)


def spread_table(rows: list[tuple[str, list[float], list[float]]], first: str = "run") -> str:
    """Markdown of ``(label, pose spread per glance, within an object per glance)`` rows under
    the heading ``first``, one column per glance (``—`` past a row's glances)."""
    width = max(len(spread) for _, spread, _ in rows)
    lines = [
        "0.577: uniform poses (a random glance); 0: one fixed path for every episode; in "
        "parentheses: within the episodes of one object.",
        "",
        f"| {first} | " + " | ".join(f"glance {s + 1}" for s in range(width)) + " |",
        "|---|" + "---|" * width,
    ]
    for label, spread, within in rows:
        cells = [f"{a:.3f} ({b:.3f})" for a, b in zip(spread, within, strict=True)]
        lines.append(f"| {label} | " + " | ".join(cells + ["—"] * (width - len(cells))) + " |")
    return "\n".join(lines)


def pose_spread_markdown(root: Path, jobs: list[Job]) -> str | None:
    """Per run group: each glance's pose spread at the last evaluation, over all episodes and
    (in parentheses) within an object, mean over the finished seeds
    (:attr:`ham.learn.evaluation.EvalResult.pose_spread`)."""
    groups: dict[tuple, list[dict]] = {}
    for j in jobs:
        history = read_metrics(run_dir(root, j.key)).get("history")
        last = history[-1] if history else {}
        if last.get("pose_spread") is not None:  # not in runs of before it was recorded
            groups.setdefault((j.variant, j.combiner, j.glances), []).append(last)
    if not groups:
        return None
    rows = []
    for (variant, combiner, glances), runs in sorted(
        groups.items(), key=lambda kv: (kv[0][2], kv[0][0], kv[0][1])
    ):
        mean = [
            [sum(r[key][s] for r in runs) / len(runs) for s in range(glances)]
            for key in ("pose_spread", "pose_spread_within_object")
        ]
        rows.append((f"{variant}-{combiner} ({len(runs)} seed(s))", *mean))
    return spread_table(rows)


KNOWN_DIFFERENCES = """\
- **Sensor images.** Our simulator shows an edge as a line along the whole contact, as the real
  Myrmex does; the paper's Gazebo plugin saw only two contact points and showed two blobs. Lines
  carry more shape information per glance, so single glances tend to be more telling here.
- **Geometry.** The paper gives the objects' shapes but not their height or the exploration zone;
  ours are 4.5 cm high and the zone is the block's 9 cm (see `docs/`), so poses and images differ.
- **Glances from a table.** Like the paper, training looks up the closest of 201 x 201 pre-recorded
  poses; `ham train --online` glances at the exact pose instead.
- **Protocol.** Profiles other than `paper` train for fewer steps and seeds; their numbers are lower
  bounds of what the full protocol reaches."""


def render_report(
    target: str,
    profile: Profile,
    sections: list[tuple[str, str]],
    figures: list[str],
    failures: list[dict],
    command: str | None,
    executor: str,
    stopped: dict[str, int] | None = None,
    steps: int | None = None,
    env: dict | None = None,
) -> str:
    env = env or environment_record()
    lines = [
        f"# ham reproduce {target} — profile `{profile.name}`",
        "",
        f"Command: `{command or 'ham reproduce ' + target + ' --profile ' + profile.name}`",
        f"Executor: {executor}. Written {time.strftime('%Y-%m-%d %H:%M:%S %Z')}.",
        "",
        f"Protocol: {profile.steps} steps, {profile.seeds} seed(s), evaluation every "
        f"{profile.eval_every} steps over {profile.eval_batches} balanced batches of 64; "
        "entries are the best accuracy within a run, mean ± standard error over seeds.",
        f"Reductions from the paper's protocol: {profile.reductions()}.",
        "",
        "Environment: " + ", ".join(f"{k} {v}" for k, v in env.items()) + ".",
        "",
    ]
    for title, md in sections:
        lines += [f"## {title}", "", md, ""]
    if figures:
        lines += ["## Figures", ""]
        lines += [f"![{Path(f).stem}]({f})" for f in figures]
        lines.append("")
    elif target in ("figures", "all"):
        lines += ["## Figures", "", "None: the figures show the full model and random "
                  "locations, and no finished run of either is in OUT.", ""]  # fmt: skip
    lines += ["## Where and why our numbers differ from the paper's", "", KNOWN_DIFFERENCES, ""]
    if stopped:
        lines += ["## Runs stopped at a perfect evaluation (--stop-at-perfect)", ""]
        lines += [f"- `{k}`: best accuracy 1.000 at step {v:,} of {steps:,}; its curve ends "
                  "there" for k, v in sorted(stopped.items())]  # fmt: skip
        lines.append("")
    if failures:
        lines += ["## Failed runs", ""]
        lines += [f"- `{f['key']}`: {f.get('error', '?')}" for f in failures]
        lines.append("")
    return "\n".join(lines)
