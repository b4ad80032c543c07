"""Executors: how a list of runs is trained (``--executor local|ray|batched|ray-batched``).

A run is a job: its key (its directory ``ROOT/runs/<key>``), its config, and evaluations of its
final checkpoint (grids). :func:`execute` trains the jobs not yet finished on one executor and
retries the failed ones; every executor reports each run's result the same way, a worker that
died included, so that the others go on:

* ``local``: single runs on a process pool (:func:`run_job`);
* ``ray``: single runs as Ray tasks, on a cluster or a Ray started here;
* ``batched``: runs of one shape trained as one batched model each (:func:`run_batch`,
  :mod:`ham.learn.batched`; grouped by :func:`group_jobs`, :class:`BatchedOptions`), the models
  on a process pool, or one after another in this process (the way to use one GPU), or
  ``groups_together`` of them at a time in one worker (on a GPU, each on its own stream);
* ``ray-batched``: those batched models as Ray tasks.

Used by ``ham reproduce`` (:mod:`ham.experiments.reproduce`) and ``ham reproduce grid``
(:mod:`ham.experiments.grid_run`).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, fields
from pathlib import Path
from typing import NamedTuple, Protocol

from ham.errors import HamError, check_types, too_large
from ham.experiments.runs import is_finished, run_dir
from ham.world.recorded_file import raised_in

EXECUTORS = ("local", "ray", "batched", "ray-batched")
#: the executors that train runs of one shape as one batched model (:mod:`ham.learn.batched`)
BATCHED_EXECUTORS = ("batched", "ray-batched")
#: the executors that run on Ray (``--ray-address``)
RAY_EXECUTORS = ("ray", "ray-batched")


class Job(Protocol):
    """What an executor reads of a job: ``ham reproduce``'s
    :class:`ham.experiments.reproduce.Job` and a grid's :class:`ham.experiments.grid.GridJob`."""

    key: str
    config: dict  # a TrainConfig's dict

    def to_dict(self) -> dict: ...


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


def _error(exc: BaseException) -> str:
    """A failed run's error: the exception, or the user's file and line it came from (a
    plugin's core failing in training: :func:`ham.world.recorded_file.raised_in`)."""
    return raised_in(exc) or too_large(exc) or f"{type(exc).__name__}: {exc}"


def _safe_run(job: dict, root: str, world: dict, grid: int) -> dict:
    try:
        return run_job(job, root, world, grid)
    except BaseException as exc:  # noqa: BLE001 - a worker must report, not die silently
        if isinstance(exc, KeyboardInterrupt):
            raise
        return {
            "key": job["key"],
            "status": "failed",
            "error": _error(exc),
            "traceback": traceback.format_exc(limit=6),
        }


# --------------------------------------------------------------------------- executors
def _worker_init(parent: int) -> None:
    """One torch thread; Ctrl-C left to the pool's owner; and the worker ends with the process
    that started it (``parent``).

    A pool's worker notices its parent's death only between tasks, and a task here is a whole
    training run: a ``kill`` of ``ham reproduce`` would leave its runs training on, and a second
    ``ham reproduce`` of the same folder would then train them twice at once, each writing the
    other's checkpoints. On Linux the kernel sends the worker SIGTERM when its parent dies
    (``PR_SET_PDEATHSIG``); the run resumes from its last checkpoint (written atomically).
    """
    import signal

    import torch

    # Ctrl-C reaches the whole process group: a worker would take it as its task's end and go
    # on to the next one; the pool's owner ends the workers instead (_on_pool)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # tqdm's default lock is a multiprocessing semaphore, which a worker ended by the pool's
    # owner could not release (the resource tracker then warns of it); a worker's bars are off
    import threading

    from tqdm import tqdm

    tqdm.set_lock(threading.RLock())
    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_pdeathsig = 1
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGTERM)
        if os.getppid() != parent:  # it died before the call
            os._exit(1)
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


class _Task(NamedTuple):
    """One worker's share: ``fn(*args)`` trains the runs ``keys`` (one run, or a batched
    model's) and returns their results."""

    fn: Callable[..., dict | list[dict]]
    args: tuple
    keys: list[str]


def _single_tasks(jobs: list[Job], root: Path, world: dict, grid: int | None) -> list[_Task]:
    """A task a run (:func:`run_job`): the local and Ray executors."""
    return [_Task(_safe_run, (j.to_dict(), str(root), world, grid), [j.key]) for j in jobs]


def _batched_tasks(
    jobs: list[Job], root: Path, world: dict, grid: int | None, options: BatchedOptions
) -> list[_Task]:
    """A task a batched model (:func:`group_jobs`, :func:`run_batch`): the batched executors.
    A run no batched model can train (:func:`unbatchable`) is a task of its own, as the local
    executor's, on the same pool."""
    single = unbatchable(jobs)
    batchable = [j for j in jobs if j.key not in single]
    groups = [[j.to_dict() for j in g]
              for g in group_jobs(batchable, options.batch_runs, options.merge_glances)]  # fmt: skip
    k = options.groups_together  # a worker's models, in plan order
    bundles = [groups[i : i + k] for i in range(0, len(groups), k)]
    tasks = [_Task(_safe_batch, (b, str(root), world, grid, options),
                   [j["key"] for g in b for j in g]) for b in bundles]  # fmt: skip
    return tasks + _single_tasks([j for j in jobs if j.key in single], root, world, grid)


def unbatchable(jobs: Iterable) -> dict[str, str]:
    """The runs among ``jobs`` (``.key``, ``.config``) that no batched model can train (a core
    other than lstm/mlp, the learned stop, another learner, ...: :func:`ham.learn.batched.
    check_batchable`), by key: why, e.g. ``core 'transformer' cannot be batched``."""
    from ham.learn.batched import check_batchable
    from ham.learn.train import TrainConfig

    out = {}
    for job in jobs:
        try:
            check_batchable(TrainConfig.from_dict(job.config))
        except HamError as exc:
            out[job.key] = str(exc).split(";")[0]
    return out


def unbatchable_note(jobs: list) -> str | None:
    """One line for the runs a batched executor trains one by one (``None`` when there are none),
    for the terminal and the report: how many, and why for the first."""
    single = unbatchable(jobs)
    if not single:
        return None
    key, why = next(iter(single.items()))
    more = f" and {len(single) - 1} more" if len(single) > 1 else ""
    return (
        f"{len(single)} of {len(jobs)} run(s) cannot be batched (run {key}: {why}{more}): they "
        "train one by one, as with --executor local (batched options do not apply to them)"
    )


def _on_pool(tasks: list[_Task], workers: int, on_result: Callable[[dict], None]) -> None:
    """The tasks on a process pool of at most ``workers`` (one torch thread each), or in this
    process when there is one task or one worker (the way to use one GPU)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    workers = min(workers, len(tasks))
    if workers <= 1:
        for t in tasks:  # _safe_run and _safe_batch report their runs' failures themselves
            for r in _results(lambda t=t: t.fn(*t.args), t.keys):
                on_result(r)
        return
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(
        max_workers=workers, mp_context=ctx, initializer=_worker_init, initargs=(os.getpid(),)
    ) as pool:
        try:
            futures = {pool.submit(t.fn, *t.args): t.keys for t in tasks}
            for fut in as_completed(futures):
                for r in _results(fut.result, futures[fut]):
                    on_result(r)
        except BaseException:
            # Ctrl-C (the workers ignore it, _worker_init) or an error here: end the workers now
            # instead of waiting for their runs (hours); each run resumes from its checkpoint
            pool.shutdown(wait=False, cancel_futures=True)
            for p in mp.active_children():
                p.terminate()
            raise


def execute_local(
    jobs: list[Job],
    root: Path,
    world: dict,
    grid: int,
    workers: int,
    on_result: Callable[[dict], None],
) -> None:
    """Single runs on a process pool over the cores, one torch thread per worker (no more
    workers than jobs; one job, or one worker, runs in this process)."""
    _on_pool(_single_tasks(jobs, root, world, grid), workers, on_result)


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


#: Settings that decide the last bits of a run's numbers on a CPU, handed on to a Ray cluster's
#: workers (a local pool's workers inherit them): ``MKL_CBWR=COMPATIBLE`` asks MKL for the same
#: results on every kind of CPU (its conditional numerical reproducibility), so that the nodes
#: of a mixed cluster give one machine's numbers.
NUMERICS_ENV: tuple[str, ...] = ("MKL_CBWR",)


def _connect_ray(address: str | None, cpus: int | None):
    """Ray, joined to the cluster at ``address`` or started here with ``cpus`` CPUs (default:
    all) unless this process is connected already; and whether it was started by this call."""
    try:
        import ray
    except ImportError:
        raise HamError("the ray executors need Ray: pip install 'ham[cluster]'") from None
    if ray.is_initialized():
        return ray, False
    kwargs = {"address": address} if address else {"num_cpus": cpus or os.cpu_count() or 1}
    numerics = {k: os.environ[k] for k in NUMERICS_ENV if k in os.environ}
    if numerics:  # the cluster's nodes compute as this machine asks (docs/results/README.md)
        kwargs["runtime_env"] = {"env_vars": numerics}
    try:
        ray.init(**kwargs, include_dashboard=False, log_to_driver=False,
                 logging_level="ERROR")  # fmt: skip
    except ConnectionError as exc:  # --ray-address auto with no cluster running
        reason = str(exc).split(". ")[0]
        if address not in (None, "auto") and os.environ.get("RAY_AUTH_MODE") != "token":
            # Ray's error does not say why; since 2.59 `ray start --head` asks for a token
            reason += (
                " (a head started with token authentication, the default of `ray start` "
                "since Ray 2.59, also needs RAY_AUTH_MODE=token here: docs/batched.md)"
            )
        raise HamError(f"--ray-address {address!r}: {reason}; accepted: {_RAY_ADDRESSES}") from None
    return ray, True


@contextlib.contextmanager
def ray_session(executor: str, address: str | None, cpus: int | None) -> Iterator[None]:
    """With a Ray executor: Ray connected (or started here) before the caller writes anything,
    so that a cluster that cannot be joined leaves no table, plan or folder behind; the Ray
    started here is shut down on leaving. Other executors: nothing."""
    if executor not in RAY_EXECUTORS:
        yield
        return
    ray, started_here = _connect_ray(address, cpus)
    try:
        yield
    finally:
        if started_here:
            ray.shutdown()


def _on_ray(
    address: str | None,
    jobs: list[Job],
    tasks: list[_Task],
    on_result: Callable[[dict], None],
    cpus: int | None,
) -> None:
    """Start Ray with ``cpus`` CPUs (default: all; tasks take one each, :func:`_ray_options`
    for the ``jobs``), or join the cluster at ``address``; run the tasks as Ray tasks, hand each
    result to ``on_result`` as it arrives, and shut down the Ray started here."""
    ray, started_here = _connect_ray(address, cpus)
    try:
        options = _ray_options(ray, jobs)
        remotes: dict[Callable, object] = {}
        keys = {}
        for t in tasks:
            if t.fn not in remotes:
                remotes[t.fn] = ray.remote(**options)(t.fn)
            keys[remotes[t.fn].remote(*t.args)] = t.keys
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
    """Single runs as Ray tasks, one CPU each (and a share of a GPU for runs on CUDA,
    :func:`gpu_share`; ``pip install ham[cluster]``); a Ray started here gets ``workers`` CPUs
    (default: all)."""
    _on_ray(address, jobs, _single_tasks(jobs, root, world, grid), on_result, workers)


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
    tasks = _batched_tasks(jobs, root, world, grid, options or BatchedOptions())
    _on_ray(address, jobs, tasks, on_result, workers)


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
        cuda_graph: each batched step replayed as one CUDA graph (needs the device cuda, SGD
            and a glance table; on an H100 5.7-8.6x faster a step than eager, docs/batched.md)
        groups_together: batched models a worker trains together, each step of all launched
            before any is read back, each model on its own CUDA stream (on one H100 with
            cuda_graph, 8-15 models gave 2.5-3x one model's throughput; on a CPU it gains
            nothing); a worker's models finish with its longest
    """

    batch_runs: int | None = None
    stop_at_perfect: bool = False
    merge_glances: bool = False
    cuda_graph: bool = False
    groups_together: int = 1

    def __post_init__(self) -> None:
        check_types(self)
        for name in ("batch_runs", "groups_together"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise HamError(f"{name} = {v!r}; accepted: an integer >= 1")

    def given(self) -> list[str]:
        """The options set (not at their defaults), as their flags."""
        return [f"--{f.name.replace('_', '-')}" for f in fields(self)
                if getattr(self, f.name) != f.default]  # fmt: skip


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
    itself would retry an address where nothing listens for minutes, logging each try.

    Ray reads the environment's ``RAY_ADDRESS`` before the address it is given (unless that is
    a ``ray://`` one) and without one instead of starting a Ray here: that address is checked
    then, and named as the environment's."""
    if ray_address is not None and executor not in RAY_EXECUTORS:
        raise HamError(f"--ray-address {ray_address!r}: accepted only with --executor "
                       f"{' or '.join(RAY_EXECUTORS)}")  # fmt: skip
    if executor not in RAY_EXECUTORS:
        return
    env = os.environ.get("RAY_ADDRESS") or None
    if env is not None and not (ray_address or "").startswith("ray://"):
        address, what = env, f"RAY_ADDRESS={env!r} (the environment's, which Ray reads first)"
        accepted = f"unset RAY_ADDRESS, or set it to {_RAY_ADDRESSES}"
    else:
        address, what, accepted = ray_address, f"--ray-address {ray_address!r}", _RAY_ADDRESSES
    if address is None or address == "auto":
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise HamError(f"{what}; accepted: {accepted}")
    import socket

    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=5) as conn:
            grpc = _speaks_http2(conn)
    except OSError as exc:
        raise HamError(
            f"{what}: nothing answers there ({exc.strerror or exc}); accepted: {accepted}"
        ) from None
    if not grpc:  # e.g. a web server: Ray would wait for a GCS there for minutes, logging
        raise HamError(
            f"{what}: something answers there, but not a Ray head (it does not speak gRPC); "
            f"accepted: {accepted}"
        )
    code = _ray_service(address)
    if code == "UNAUTHENTICATED" and os.environ.get("RAY_AUTH_MODE") != "token":
        # Ray itself would log InvalidAuthToken for 20-30 s, then fail without saying why
        raise HamError(
            f"{what}: a Ray head answers there and asks for its auth token (token "
            "authentication, the default of `ray start` since Ray 2.59); accepted: "
            "RAY_AUTH_MODE=token in this environment (docs/batched.md)"
        )
    if code in ("UNIMPLEMENTED", "DEADLINE_EXCEEDED", "UNAVAILABLE"):
        # another gRPC server: Ray's GCS client would wait for it without end
        raise HamError(
            f"{what}: a gRPC server answers there, but not a Ray head (its "
            f"{_RAY_METHODS['client' if address.startswith('ray://') else 'gcs']}: {code}); "
            f"accepted: {accepted}"
        )


#: HTTP/2's client connection preface and an empty SETTINGS frame (RFC 9113, 3.4 and 6.5).
_HTTP2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])


def _speaks_http2(conn) -> bool:
    """Whether the server on ``conn`` answers HTTP/2's preface with its SETTINGS frame, as every
    gRPC server does (a Ray head's GCS and its Ray Client server both are gRPC servers)."""
    try:
        conn.sendall(_HTTP2_HELLO)
        head = b""
        while len(head) < 9:  # a frame header: 3 bytes length, 1 byte type (4: SETTINGS), ...
            part = conn.recv(9 - len(head))
            if not part:
                break
            head += part
    except OSError:  # a timeout too
        return False
    return len(head) == 9 and head[3] == 4


#: A method each kind of Ray head serves: the GCS (``HOST:PORT``) and the Ray Client server
#: (``ray://HOST:PORT``); their request messages may be empty.
_RAY_METHODS = {
    "gcs": "/ray.rpc.NodeInfoGcsService/GetClusterId",
    "client": "/ray.rpc.RayletDriver/ClusterInfo",
}


def _ray_service(address: str) -> str | None:
    """The gRPC status name of the Ray method of its kind called at ``address`` with an empty
    request (``None``: answered, or grpcio missing): a Ray head answers it, or refuses it with
    UNAUTHENTICATED when it asks for a token; a server of another service says UNIMPLEMENTED."""
    try:
        import grpc  # Ray's own dependency, there wherever the Ray executors can run
    except ImportError:  # pragma: no cover - Ray's executors then say they need Ray
        return None
    method = _RAY_METHODS["client" if address.startswith("ray://") else "gcs"]
    with grpc.insecure_channel(address.removeprefix("ray://")) as channel:
        try:
            channel.unary_unary(method)(b"", timeout=10)
        except grpc.RpcError as exc:
            return exc.code().name
    return None


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


def run_batch(
    groups: list[list[dict]],
    root: str,
    world: dict,
    grid: int | None,
    options: BatchedOptions | None = None,
) -> list[dict]:
    """Train each group of jobs (one shape) as one batched model (:mod:`ham.learn.batched`),
    the groups together (``options.groups_together`` of them: each on its own CUDA stream); each
    run resumes from its checkpoint if it has one. Returns one result per job, as
    :func:`run_job`: a run that diverged fails alone; then each finished run's ``evaluate``
    specs."""
    import torch

    from ham.learn.batched import train_batched_together
    from ham.learn.train import TrainConfig

    # one torch thread, as run_job and the pool's workers: in this process (one worker or one
    # group) the default thread count made only the first group use every core, and on a loaded
    # machine two spinning threads per process slowed its step many times over
    torch.set_num_threads(1)
    started = time.perf_counter()
    options = options or BatchedOptions()
    jobs = [j for g in groups for j in g]
    todo = [[j for j in g if not is_finished(run_dir(Path(root), j["key"]), j["config"]["steps"])]
            for g in groups]  # fmt: skip
    todo = [g for g in todo if g]
    errors: dict[str, str] = {}
    batches = []
    for g in todo:
        configs = [TrainConfig.from_dict(j["config"]) for j in g]
        if configs[0].table is not None:
            _ensure_table(Path(configs[0].table), g[0].get("world", world), grid)
        batches.append((configs, [run_dir(Path(root), j["key"]) for j in g]))
    if batches:
        results = train_batched_together(batches, stop_at_perfect=options.stop_at_perfect,
                                         cuda_graph=options.cuda_graph)  # fmt: skip
        # a string: the run diverged and left the batch (its folder keeps its last checkpoint)
        errors = {j["key"]: r for g, rs in zip(todo, results, strict=True)
                  for j, r in zip(g, rs, strict=True) if isinstance(r, str)}  # fmt: skip
    trained = {j["key"] for g in todo for j in g}
    seconds = (time.perf_counter() - started) / len(jobs)
    out = []
    for j in jobs:
        if j["key"] in errors:
            out.append(
                {"key": j["key"], "status": "failed", "error": f"DivergedError: {errors[j['key']]}"}
            )
            continue
        r = _safe_run(j, root, world, grid)  # finished: only its evaluations, if any
        if r["status"] != "failed":
            r["status"] = "done" if j["key"] in trained else r["status"]
            r["seconds"] = seconds + r["seconds"]
        out.append(r)
    return out


def _safe_batch(
    groups: list[list[dict]], root: str, world: dict, grid: int, options: BatchedOptions
) -> list[dict]:
    jobs = [j for g in groups for j in g]
    try:
        return run_batch(groups, root, world, grid, options)
    except BaseException as exc:  # noqa: BLE001 - a worker must report, not die silently
        if isinstance(exc, KeyboardInterrupt):
            raise
        error = _error(exc)
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
    tasks = _batched_tasks(jobs, root, world, grid, options or BatchedOptions())
    _on_pool(tasks, workers, on_result)


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

    A run that diverged is not retried: it would resume from its last checkpoint and repeat the
    same numbers.

    Returns every run's last result by key and the results of the runs that failed every try
    (or diverged).
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
    diverged: list = []
    for attempt in range(retries + 1):
        if not todo:
            break
        if executor in BATCHED_EXECUTORS:
            tasks = _batched_tasks(todo, root, world, grid, batched)
        else:
            tasks = _single_tasks(todo, root, world, grid)
        if attempt:
            print(f"retrying {len(todo)} failed run(s) (attempt {attempt + 1})", file=sys.stderr)
        elif progress and executor == "batched" and len(tasks) < workers:
            if max(len(t.keys) for t in tasks) > 1:
                # the grouping does not follow --workers: the same command gives the same
                # numbers on any machine (a run's last bits depend on its batch's size)
                print(f"{len(tasks)} batched model(s) for {workers} workers: --batch-runs N "
                      "spreads one shape's runs over more models", file=sys.stderr)  # fmt: skip
        if executor in RAY_EXECUTORS:
            _on_ray(ray_address, todo, tasks, on_result, workers)
        else:
            _on_pool(tasks, workers, on_result)
        failed = [j for j in todo if results.get(j.key, {}).get("status") == "failed"]
        # a diverged run resumes from its last checkpoint and repeats the same numbers: a retry
        # would only spend its steps again
        new = [j for j in failed if _diverged(results[j.key])]
        todo = [j for j in failed if not _diverged(results[j.key])]
        diverged += new
        if new and attempt < retries:
            print(f"not retrying {len(new)} diverged run(s): each would resume from its "
                  "checkpoint and diverge again", file=sys.stderr)  # fmt: skip
    bar.close()
    return results, [results[j.key] for j in diverged + todo]


def _diverged(result: dict) -> bool:
    """Whether a failed run's result is a divergence (NaN/inf in its loss or weights)."""
    return result.get("error", "").startswith("DivergedError:")
