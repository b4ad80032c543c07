"""Reproduce the paper's results: Table 1, Table 2 and the figures (section "Results").

``ham reproduce {table1,table2,figures,all} --profile {smoke,quick,paper} --out DIR`` plans a grid
of training runs, runs what is not finished yet (locally on a process pool, or as Ray tasks),
and writes Markdown + JSON tables with the paper's numbers beside ours, figures, and
``DIR/report.md``.

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
import platform
import sys
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ham.errors import HamError
from ham.experiments.runs import is_finished, per_object_accuracy, run_dir

if TYPE_CHECKING:
    from ham.world.config import WorldConfig

TARGETS = ("table1", "table2", "figures", "all")
EXECUTORS = ("local", "ray", "batched", "ray-batched")
#: the executors that train runs of one shape as one batched model (:mod:`ham.learn.batched`)
BATCHED_EXECUTORS = ("batched", "ray-batched")
#: the executors that run on Ray (``--ray-address``)
RAY_EXECUTORS = ("ray", "ray-batched")

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


# --------------------------------------------------------------------------- run one job
def run_job(job: dict, root: str, world: dict, grid: int | None) -> dict:
    """Train one run to completion (resuming it if it was interrupted); runs in a worker.

    The worker builds the glance table itself when it is missing (on a cluster node without the
    shared file): the build is deterministic, so every node trains on identical glances. A run
    without a table (``config.table`` is ``None``) glances online. The job's ``evaluate`` specs
    (grids) re-evaluate the final checkpoint, once each.
    """
    import torch

    from ham.experiments.runs import evaluate_final, has_evaluation
    from ham.learn.train import TrainConfig, resume, train

    torch.set_num_threads(1)
    started = time.perf_counter()
    out = run_dir(Path(root), job["key"])
    config = TrainConfig.from_dict(job["config"])
    status = "skipped"
    if not is_finished(out, config.steps):
        if config.table is not None:
            # a grid cell's own world (docs/grids.md), else the grid's
            _ensure_table(Path(config.table), job.get("world", world), grid)
        if (out / "checkpoint.pt").exists():
            resume(out, progress=False)
        else:
            train(config, out, progress=False)
        status = "done"
    for spec in job.get("evaluate", ()):
        if not has_evaluation(out, spec, config.steps):
            evaluate_final(out, spec)
            status = "done"
    return {"key": job["key"], "status": status, "seconds": time.perf_counter() - started}


def _ensure_table(path: Path, world: dict, grid: int) -> None:
    if path.exists():
        return
    from ham.world.config import WorldConfig
    from ham.world.table import build_table

    build_table(WorldConfig.from_dict(world), grid, path, progress=False, command="ham reproduce")


def _safe_run(job: dict, root: str, world: dict, grid: int) -> dict:
    try:
        return run_job(job, root, world, grid)
    except BaseException as exc:  # noqa: BLE001 - a worker must report, not die silently
        if isinstance(exc, KeyboardInterrupt):
            raise
        return {
            "key": job["key"],
            "status": "failed",
            "error": f"{type(exc).__name__}: {exc}",
            "traceback": traceback.format_exc(limit=6),
        }


# --------------------------------------------------------------------------- executors
def _worker_init() -> None:
    import torch

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch.set_num_threads(1)


def _results(get: Callable[[], dict | list[dict]], keys: list[str]) -> list[dict]:
    """A worker's results (one run's or a batch's), or, where the worker itself died (killed,
    out of memory: its pool or Ray says so), each of its runs as failed with that reason, so the
    other runs go on and the retries re-run these from their checkpoints."""
    try:
        r = get()
    except Exception as exc:  # noqa: BLE001 - any way a worker can be lost
        lines = str(exc).strip().splitlines()
        reason = f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__
        return [{"key": k, "status": "failed", "error": f"the worker died ({reason})"}
                for k in keys]  # fmt: skip
    return r if isinstance(r, list) else [r]


def execute_local(
    jobs: list[Job],
    root: Path,
    world: dict,
    grid: int,
    workers: int,
    on_result: Callable[[dict], None],
) -> None:
    """A process pool over the cores, one torch thread per worker (no more workers than jobs;
    one job, or one worker, runs in this process)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    workers = min(workers, len(jobs))
    if workers <= 1:
        for job in jobs:
            on_result(_safe_run(job.to_dict(), str(root), world, grid))
        return
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init) as pool:
        futures = {pool.submit(_safe_run, j.to_dict(), str(root), world, grid): [j.key]
                   for j in jobs}  # fmt: skip
        for fut in as_completed(futures):
            for r in _results(fut.result, futures[fut]):
                on_result(r)


def gpu_share(resources: dict) -> float:
    """The share of a GPU a Ray task of one CPU asks for when its runs are on CUDA: the
    cluster's GPUs over its CPUs, so that as many tasks run at once as there are CPUs, spread
    evenly over the GPUs (1 GPU and 16 CPUs: 16 tasks on the GPU; 8 GPUs and 64 CPUs: 8 on
    each), at most one GPU; rounded down to Ray's 1e-4 resolution."""
    gpus, cpus = float(resources.get("GPU", 0)), float(resources.get("CPU", 0))
    if gpus <= 0:
        raise HamError(
            "runs on cuda, but the Ray cluster has no GPU; accepted: --device cpu, or a cluster "
            "whose nodes have GPUs (ray start --num-gpus N)"
        )
    return max(min(1.0, math.floor(gpus / max(cpus, 1.0) * 1e4) / 1e4), 1e-4)


def _ray_options(ray, jobs: list[Job]) -> dict:
    """One CPU per task, and its share of a GPU (:func:`gpu_share`) when the runs are on CUDA:
    Ray then points each task's ``CUDA_VISIBLE_DEVICES`` at the GPU it was given."""
    options = {"num_cpus": 1, "max_retries": 0}
    if any(str(j.config.get("device", "cpu")).startswith("cuda") for j in jobs):
        options["num_gpus"] = gpu_share(ray.cluster_resources())
    return options


def _on_ray(
    address: str | None, submit: Callable, on_result: Callable[[dict], None], cpus: int | None
) -> None:
    """Start Ray with ``cpus`` CPUs (default: all; tasks take one each), or join the cluster at
    ``address``; submit the tasks ``submit(ray)`` returns (each task's reference -> the keys of
    its runs), hand each result to ``on_result`` as it arrives, and shut down the Ray started
    here."""
    try:
        import ray
    except ImportError:
        raise HamError("the ray executors need Ray: pip install 'ham[cluster]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        kwargs = {"address": address} if address else {"num_cpus": cpus or os.cpu_count() or 1}
        try:
            ray.init(**kwargs, include_dashboard=False, log_to_driver=False,
                     logging_level="ERROR")  # fmt: skip
        except ConnectionError as exc:  # --ray-address auto with no cluster running
            reason = str(exc).split(". ")[0]
            raise HamError(
                f"--ray-address {address!r}: {reason}; accepted: {_RAY_ADDRESSES}"
            ) from None
    try:
        keys = submit(ray)
        pending = list(keys)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                for r in _results(lambda ref=ref: ray.get(ref), keys[ref]):
                    on_result(r)
    finally:
        if started_here:
            ray.shutdown()


def execute_ray(
    jobs: list[Job],
    root: Path,
    world: dict,
    grid: int,
    address: str | None,
    on_result: Callable[[dict], None],
    workers: int | None = None,
) -> None:
    """The same grid as Ray tasks, one CPU each (and a share of a GPU for runs on CUDA,
    :func:`gpu_share`; ``pip install ham[cluster]``); a Ray started here gets ``workers`` CPUs
    (default: all)."""

    def submit(ray):
        remote = ray.remote(**_ray_options(ray, jobs))(_safe_run)
        return {remote.remote(j.to_dict(), str(root), world, grid): [j.key] for j in jobs}

    _on_ray(address, submit, on_result, workers)


def execute_ray_batched(
    jobs: list[Job],
    root: Path,
    world: dict,
    grid: int,
    address: str | None,
    on_result: Callable[[dict], None],
    options: BatchedOptions | None = None,
    workers: int | None = None,
) -> None:
    """The batched executor's groups (:func:`group_jobs`) as Ray tasks, one CPU each (a Ray
    started here gets ``workers`` CPUs, default all): Ray hands each node whole batched models,
    as many at once as the node has CPUs; groups on CUDA each take a share of a GPU
    (:func:`gpu_share`), so that they spread evenly over a node's GPUs."""

    options = options or BatchedOptions()

    def submit(ray):
        remote = ray.remote(**_ray_options(ray, jobs))(_safe_batch)
        groups = [[j.to_dict() for j in g] for g in _groups(jobs, options)]
        return {remote.remote(g, str(root), world, grid, options): [j["key"] for j in g]
                for g in groups}  # fmt: skip

    _on_ray(address, submit, on_result, workers)


@dataclass(frozen=True)
class BatchedOptions:
    """How the batched executors (``--executor batched`` or ``ray-batched``) group runs into
    batched models and train them (:mod:`ham.learn.batched`, docs/batched.md).

    Attributes:
        batch_runs: at most this many runs of one shape per batched model (default: a shape's
            runs in near-equal models of at most 10)
        stop_at_perfect: stop a run whose best evaluation is 1.000 (its table entry cannot
            change); its metrics.json says stopped_at_perfect
        merge_glances: runs of other glance counts (2 or more) in one model, which steps its
            longest run's glances; a shape's runs in one model unless batch_runs caps it (fewer
            models: for a GPU, where a step costs its kernel launches; on a CPU it costs more)
        cuda_graph: each batched step replayed as one CUDA graph (needs the device cuda and
            SGD; not yet measured on a GPU)
    """

    batch_runs: int | None = None
    stop_at_perfect: bool = False
    merge_glances: bool = False
    cuda_graph: bool = False

    def __post_init__(self) -> None:
        b = self.batch_runs
        if b is not None and not (isinstance(b, int) and not isinstance(b, bool) and b >= 1):
            raise HamError(f"batch_runs = {b!r}; accepted: an integer >= 1")
        for name in ("stop_at_perfect", "merge_glances", "cuda_graph"):
            if not isinstance(getattr(self, name), bool):
                raise HamError(f"{name} = {getattr(self, name)!r}; accepted: true or false")

    def given(self) -> list[str]:
        """The options set, as their flags."""
        return [f"--{name.replace('_', '-')}" for name, v in asdict(self).items()
                if v not in (None, False)]  # fmt: skip


def check_batched_options(
    executor: str, options: BatchedOptions, devices: Iterable[str] = ()
) -> None:
    """``options`` need a batched executor, and a CUDA graph the runs' ``devices`` all CUDA."""
    if executor not in BATCHED_EXECUTORS:
        given = options.given()
        if given:
            verb = "needs" if len(given) == 1 else "need"
            raise HamError(f"{', '.join(given)} {verb} --executor batched or ray-batched "
                           f"(got {executor!r})")  # fmt: skip
    if options.cuda_graph:
        other = sorted({d for d in devices if not str(d).startswith("cuda")})
        if other:
            raise HamError(f"--cuda-graph needs --device cuda (a CPU has no CUDA graphs); got "
                           f"{other[0]!r}")  # fmt: skip


_RAY_ADDRESSES = "auto, HOST:PORT or ray://HOST:PORT of a running Ray head (ray start --head)"


def check_ray_address(executor: str, ray_address: str | None) -> None:
    """``ray_address`` goes with the Ray executors only, and a ``HOST:PORT`` must answer: Ray
    itself would retry an address where nothing listens for minutes, logging each try."""
    if ray_address is None:
        return
    if executor not in RAY_EXECUTORS:
        raise HamError(f"--ray-address {ray_address!r}: accepted only with --executor "
                       f"{' or '.join(RAY_EXECUTORS)}")  # fmt: skip
    if ray_address == "auto":
        return
    host, _, port = ray_address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise HamError(f"--ray-address {ray_address!r}; accepted: {_RAY_ADDRESSES}")
    import socket

    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=5).close()
    except OSError as exc:
        raise HamError(
            f"--ray-address {ray_address!r}: nothing answers there ({exc.strerror or exc}); "
            f"accepted: {_RAY_ADDRESSES}"
        ) from None


# Runs per batched model by default: the paper's seeds of a cell, and the N the batched step was
# measured at (docs/batched.md); a larger shape (a sweep) is cut into near-equal models
# of at most this many, so that it still spreads over the workers
BATCH_RUNS = 10


def group_jobs(
    jobs: list, batch_runs: int | None = None, merge_glances: bool = False
) -> list[list]:
    """Jobs of one shape (the same config but the fields each run of a batched model keeps
    its own, :data:`ham.learn.batched.PER_RUN`: the seed, the learning-rate schedule, the
    momentum, the loss, the normalization, the evaluation settings, the BPTT truncation; with
    ``merge_glances`` the glance count too, from 2 glances on) together, in plan order: at most
    ``batch_runs`` per group, or by default near-equal groups of at most :data:`BATCH_RUNS`
    (with ``merge_glances`` one group per shape: a Table 1 column's 2-10-glance runs in one).
    Not by the number of workers: a run's last bits depend on the size of its batch, and the
    same command gives the same numbers anywhere."""
    from ham.learn.batched import shape_key
    from ham.learn.train import TrainConfig

    shapes: dict[str, list] = {}
    for j in jobs:
        config = TrainConfig.from_dict(j.config)
        key = shape_key(config, glances=not merge_glances)
        shapes.setdefault(key + f"|{config.steps}", []).append(j)
    if batch_runs:
        return [
            g[k : k + batch_runs] for g in shapes.values() for k in range(0, len(g), batch_runs)
        ]
    if merge_glances:  # fewer models is the point: a shape's runs all in one
        return list(shapes.values())
    groups = []
    for g in shapes.values():  # -(-n // m): the fewest groups of at most BATCH_RUNS
        parts = -(-len(g) // BATCH_RUNS)
        q, r = divmod(len(g), parts)
        starts = [k * q + min(k, r) for k in range(parts + 1)]
        groups += [g[a:b] for a, b in zip(starts, starts[1:], strict=False)]
    return groups


def _groups(jobs: list, options: BatchedOptions) -> list[list]:
    return group_jobs(jobs, options.batch_runs, options.merge_glances)


def run_batch(
    jobs: list[dict],
    root: str,
    world: dict,
    grid: int | None,
    options: BatchedOptions | None = None,
) -> list[dict]:
    """Train the jobs of one shape as one batched model (:mod:`ham.learn.batched`); each run
    resumes from its checkpoint if it has one. Returns one result per job, as :func:`run_job`:
    a run that diverged fails alone; then each finished run's ``evaluate`` specs."""
    import torch

    from ham.learn.batched import train_batched
    from ham.learn.train import TrainConfig

    # one torch thread, as run_job and the pool's workers: in this process (one worker or one
    # group) the default thread count made only the first group use every core, and on a loaded
    # machine two spinning threads per process slowed its step many times over
    torch.set_num_threads(1)
    started = time.perf_counter()
    todo = [j for j in jobs if not is_finished(run_dir(Path(root), j["key"]), j["config"]["steps"])]
    errors: dict[str, str] = {}
    if todo:
        configs = [TrainConfig.from_dict(j["config"]) for j in todo]
        if configs[0].table is not None:
            _ensure_table(Path(configs[0].table), todo[0].get("world", world), grid)
        outs = [run_dir(Path(root), j["key"]) for j in todo]
        options = options or BatchedOptions()
        results = train_batched(configs, outs, stop_at_perfect=options.stop_at_perfect,
                                cuda_graph=options.cuda_graph)  # fmt: skip
        errors = {j["key"]: r for j, r in zip(todo, results, strict=True) if isinstance(r, str)}
    seconds = (time.perf_counter() - started) / len(jobs)
    out = []
    for j in jobs:
        if j["key"] in errors:
            out.append(
                {"key": j["key"], "status": "failed", "error": f"HamError: {errors[j['key']]}"}
            )
            continue
        r = _safe_run(j, root, world, grid)  # finished: only its evaluations, if any
        if r["status"] != "failed":
            r["status"] = "done" if j in todo else r["status"]
            r["seconds"] = seconds + r["seconds"]
        out.append(r)
    return out


def _safe_batch(
    jobs: list[dict], root: str, world: dict, grid: int, options: BatchedOptions
) -> list[dict]:
    try:
        return run_batch(jobs, root, world, grid, options)
    except BaseException as exc:  # noqa: BLE001 - a worker must report, not die silently
        if isinstance(exc, KeyboardInterrupt):
            raise
        error = f"{type(exc).__name__}: {exc}"
        tb = traceback.format_exc(limit=6)
        return [
            {"key": j["key"], "status": "failed", "error": error, "traceback": tb} for j in jobs
        ]


def execute_batched(
    jobs: list[Job],
    root: Path,
    world: dict,
    grid: int,
    workers: int,
    on_result: Callable[[dict], None],
    options: BatchedOptions | None = None,
) -> None:
    """Jobs of one shape trained as one batched model each (:func:`group_jobs`); the
    groups on a process pool of ``workers`` (one torch thread each), or in this process when
    there is one group or one worker (the way to use one GPU)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    options = options or BatchedOptions()
    groups = [[j.to_dict() for j in g] for g in _groups(jobs, options)]
    workers = min(workers, len(groups))
    if workers <= 1:
        for g in groups:
            for r in _safe_batch(g, str(root), world, grid, options):
                on_result(r)
        return
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init) as pool:
        futures = {pool.submit(_safe_batch, g, str(root), world, grid, options):
                   [j["key"] for j in g] for g in groups}  # fmt: skip
        for fut in as_completed(futures):
            for r in _results(fut.result, futures[fut]):
                on_result(r)


def execute(
    jobs: list,
    todo: list,
    root: Path,
    world: dict,
    grid: int | None,
    *,
    executor: str,
    workers: int,
    ray_address: str | None,
    retries: int,
    progress: bool,
    desc: str,
    batched: BatchedOptions | None = None,
) -> tuple[dict[str, dict], list[dict]]:
    """Run ``todo`` (a part of ``jobs``) on ``executor``, re-running failed runs ``retries`` times.

    ``batched`` goes with the batched executors only.

    Returns every run's last result by key and the results of the runs that failed every try.
    """
    from tqdm.auto import tqdm

    results: dict[str, dict] = {}
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc=desc, unit="run",
               disable=not progress, file=sys.stderr)  # fmt: skip

    def on_result(r: dict) -> None:
        results[r["key"]] = r
        if r["status"] != "failed":
            bar.update(1)
        bar.set_postfix(failed=sum(x["status"] == "failed" for x in results.values()))

    batched = batched or BatchedOptions()
    if progress and executor == "batched" and todo:
        models = _groups(todo, batched)
        if len(models) < workers and max(len(g) for g in models) > 1:
            # the grouping does not follow --workers: the same command gives the same numbers
            # on any machine (a run's last bits depend on its batch's size)
            print(f"{len(models)} batched model(s) for {workers} workers: --batch-runs N spreads "
                  "one shape's runs over more models", file=sys.stderr)  # fmt: skip
    for attempt in range(retries + 1):
        if not todo:
            break
        if attempt:
            print(f"retrying {len(todo)} failed run(s) (attempt {attempt + 1})", file=sys.stderr)
        if executor == "ray":
            execute_ray(todo, root, world, grid, ray_address, on_result, workers)
        elif executor == "ray-batched":
            execute_ray_batched(todo, root, world, grid, ray_address, on_result, batched,
                                workers)  # fmt: skip
        elif executor == "batched":
            execute_batched(todo, root, world, grid, workers, on_result, batched)
        else:
            execute_local(todo, root, world, grid, workers, on_result)
        todo = [j for j in todo if results.get(j.key, {}).get("status") == "failed"]
    bar.close()
    return results, [results[j.key] for j in todo]


# --------------------------------------------------------------------------- aggregate
def mean_sem(values: Iterable[float]) -> tuple[float, float, int]:
    v = np.asarray(list(values), dtype=float)
    if v.size == 0:
        return math.nan, math.nan, 0
    sem = float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else math.nan
    return float(v.mean()), sem, int(v.size)


def _fmt(mean: float, sem: float, n: int) -> str:
    if n == 0 or math.isnan(mean):
        return "—"
    if n == 1 or math.isnan(sem):
        return f"{mean:.3f} (n=1)"
    return f"{mean:.3f} ± {sem:.3f}"


def load_metrics(root: Path, jobs: list[Job]) -> dict[str, dict]:
    out = {}
    for job in jobs:
        path = run_dir(root, job.key) / "metrics.json"
        if path.exists():
            out[job.key] = json.loads(path.read_text())
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
            cells += [_fmt(r["mean"], r["sem"], r["n"]), paper]
        lines.append(f"| {g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def table2_markdown(rows: dict) -> str:
    lines = ["| combiner | ours | paper |", "|---|---|---|"]
    for c, r in rows.items():
        paper = f"{r['paper'][0]:.3f} ± {r['paper'][1]:.3f}"
        lines.append(f"| {COMBINER_NAMES[c]} | {_fmt(r['mean'], r['sem'], r['n'])} | {paper} |")
    return "\n".join(lines)


# --------------------------------------------------------------------------- the command
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
    from ham.world.cache import cached_table
    from ham.world.config import WorldConfig
    from ham.world.devices import check_device
    from ham.world.files import check_output_dir
    from ham.world.table import build_table

    if target not in TARGETS:
        raise HamError(f"target {target!r}; accepted: {', '.join(TARGETS)}")
    if profile_name not in PROFILES:
        raise HamError(f"profile {profile_name!r}; accepted: {', '.join(PROFILES)}")
    if executor not in EXECUTORS:
        raise HamError(f"executor {executor!r}; accepted: {', '.join(EXECUTORS)}")
    batched = batched or BatchedOptions()
    check_batched_options(executor, batched, [device])
    profile = PROFILES[profile_name]
    if seeds is not None:
        if not (isinstance(seeds, int) and seeds >= 1):
            raise HamError(f"seeds = {seeds!r}; accepted: an integer >= 1")
        profile = replace(profile, seeds=seeds)
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
    root.mkdir(parents=True, exist_ok=True)
    world = world or WorldConfig()
    table = root / f"table_{profile.table_grid}.h5"
    if table_cache:
        table = cached_table(world, profile.table_grid, cache_dir, progress=progress,
                             command=command or "ham reproduce")  # fmt: skip
    elif table.exists():
        _check_table_objects(table, world)
    else:
        build_table(
            world, profile.table_grid, table, progress=progress, command=command or "ham reproduce"
        )
    jobs = plan(target, profile, profile.seeds, str(table), device, world.to_dict(), eval_policy)
    (root / "plan.json").write_text(json.dumps([j.to_dict() for j in jobs], indent=1))

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
        (root / "table1.md").write_text(md + "\n")
        _write_json(root / "table1.json", {str(k): v for k, v in t1.items()})
        summary["table1"] = t1
        sections.append(("Table 1: best accuracy per number of glances", md))
    if target in ("table2", "all"):
        t2 = table2(root, jobs)
        md = table2_markdown(t2)
        (root / "table2.md").write_text(md + "\n")
        _write_json(root / "table2.json", t2)
        summary["table2"] = t2
        sections.append(("Table 2: what & where combiners, 3 glances", md))
    per_object = per_object_markdown(root, jobs)
    if per_object:
        sections.append(("Accuracy per object (last evaluation, mean over seeds)", per_object))
    figures = []
    if target in ("figures", "all"):
        figures = draw_figures(root, jobs, profile)
    summary["figures"] = [str(Path(f).relative_to(root)) for f in figures]
    summary["stopped_at_perfect"] = stopped_at_perfect(root, jobs)
    _write_json(root / "summary.json", summary)
    report = render_report(
        target, profile, sections, summary["figures"], failures, command, executor,
        stopped=summary["stopped_at_perfect"], steps=profile.steps,
    )  # fmt: skip
    (root / "report.md").write_text(report)
    return summary


def stopped_at_perfect(root: Path, jobs: list[Job]) -> dict[str, int]:
    """The runs that ``--stop-at-perfect`` stopped: run key -> the step of their perfect
    evaluation (their curves end there)."""
    from ham.learn.batched import STOPPED_KEY

    out = {}
    for j in jobs:
        path = run_dir(root, j.key) / "metrics.json"
        if path.exists():
            step = json.loads(path.read_text()).get(STOPPED_KEY)
            if step is not None:
                out[j.key] = step
    return out


def per_object_markdown(root: Path, jobs: list[Job]) -> str | None:
    """Per run group (variant, combiner, glances): each object's accuracy after the last glance
    at the last evaluation (its confusion matrix), mean over the finished seeds."""
    groups: dict[tuple, list[dict]] = {}
    objects: list[str] | None = None
    for j in jobs:
        path = run_dir(root, j.key) / "metrics.json"
        if not path.exists():
            continue
        m = json.loads(path.read_text())
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


def _write_json(path: Path, obj) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1, default=str))
    os.replace(tmp, path)


def _environment() -> dict:
    import torch

    import ham
    from ham.world.devices import cpu_info

    cpu = cpu_info("model name") or platform.processor() or platform.machine()
    return {
        "ham": ham.__version__,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": np.__version__,
        "platform": platform.platform(),
        "cpu": cpu,
        "cores": os.cpu_count(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none",
    }


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
) -> str:
    env = _environment()
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
