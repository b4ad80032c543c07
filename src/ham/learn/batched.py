"""Batched training: N runs of one shape trained as one stacked model (beyond the paper).

The paper's grid is hundreds of small runs (LSTM 256, batch 64); one run at a time pays every
operation's overhead for a few small matrices. Here N runs whose configs differ only in
:data:`PER_RUN` fields (``seed``, ``steps``, the learning-rate schedule, the momentum, the loss's
``beta`` and reductions, the normalization, the pose noise and the read-out's spread
augmentation, the BPTT truncation, the evaluation and logging settings: the seeds of a grid cell,
or a sweep of rates; and the glance count, 2 or more, where the grouping asks for it:
:func:`shape_key`) go through each step together: their weights are stacked along a leading run
axis, one glance of all N runs is one pass through the stacked layers
(:class:`ham.learn.stacked_ham.StackedHam`, mirroring :mod:`ham.model` line by line: its products,
deferred weight gradients and fused LSTM cell are described there), the hybrid loss is
:func:`torch.vmap` of :func:`ham.learn.hybrid_loss.hybrid_loss`, one backward yields every run's
gradient (the runs' graphs are disjoint), and one fused SGD call steps all runs
(docs/batched.md has the measurements). The step's work on the device asks the host nothing
(:meth:`BatchedRuns._device_step`): one read of the runs' flags is its only sync, and with
``cuda_graph`` it is captured once as a CUDA graph and replayed.

Everything else stays per run and is the single run's own code (:mod:`ham.learn.train`): each run
is a :class:`ham.learn.train.Run` with its own environment generator (objects, stream 0), pose
generator (stream 1), optimizer (SGD with Nesterov momentum at its own learning-rate schedule),
evaluation poses (stream 2), checkpoint, ``config.json``, ``metrics.json``, ``timing.json`` and
``tb/``. The runs due for an evaluation are evaluated at once (:meth:`BatchedRuns.evaluate`: the
single evaluation's counts, each run's poses from its own generator, eight evaluation batches per
pass through the stacked layers). A run's parameters (and its SGD momentum buffers) are views into
the stacked tensors, so its evaluation reads the current weights and its checkpoint the current
state. The same seed gives the single run's numbers to float tolerance (the batched products sum in
another order); resume is bit-identical to an uninterrupted batched group. A run whose loss or
weights turn NaN/inf stops alone (its directory keeps its last checkpoint), the others go on. With
``stop_at_perfect`` a run whose best evaluation reaches 1.0 stops (its best accuracy can no longer
change); its metrics say ``"stopped_at_perfect": step``.

Only the hybrid learner on the haptic world with a random first glance is batched; anything else is
refused with one line (train it with ``ham train`` or ``--executor local``).
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import torch
from torch.nn import functional as F

from ham.errors import HamError, brief, checked_arguments
from ham.learn.evaluation import EvalResult, eval_result, pose_sums
from ham.learn.hybrid_loss import hybrid_loss
from ham.learn.stacked_ham import StackedHam
from ham.learn.train import (
    CHECKPOINT_FILE,
    CONFIG_FILE,
    METRICS_FILE,
    TIMING_FILE,
    Run,
    TrainConfig,
    check_loss,
    check_weights,
    evaluate_run,
    haptic_env,
    load_checkpoint,
    log_evaluation,
    overflowed,
    read_run_config,
    start_from,
    stream_seed,
)
from ham.model.agent import Episode
from ham.model.location_net import truncated_normal, uniform_locations
from ham.model.policy import TruncatedGaussian, Uniform
from ham.world.devices import environment_record, source_commit
from ham.world.files import atomic_write, folder_lock, write_json
from ham.world.source import OnlineSource, check_model_fits, make_source

STOPPED_KEY = "stopped_at_perfect"
#: the biases a learned first glance reads (BatchedRuns._first_glance)
_FIRST_BIASES = ("location.mu.bias", "location.sigma.bias", "baseline.dense.bias")
_PARTS = ("classification", "reinforce", "baseline_loss")  # TensorBoard, as train_loop


# What may differ between the runs of one batched model: each run steps at its own learning
# rate (its schedule, its location network's scale) and momentum (Nesterov or not), has its own
# loss (beta, the reductions over the batch, the glances classified and rewarded, the returns'
# discount), normalizes its glances its own way, and is evaluated and logged on its own cadence,
# batches and policy, and may start from another run's weights (init_from); and of the model,
# whether its core's state is detached between glances (model.truncate_bptt). Everything else (the model, the world, the optimizer, the batch) is one
# for the group.
PER_RUN = ("seed", "steps", "lr", "lr_decay", "lr_step", "lr_min", "momentum", "nesterov",
           "policy_lr_scale", "beta", "classification_reduction", "reinforce_reduction",
           "classification_glances", "reward_glances", "reward_discount", "glance_reduction",
           "normalization", "eval_every", "eval_batches", "eval_policy", "log_every",
           "pose_noise", "init_from", "spread_augment")  # fmt: skip


def shape_key(config: TrainConfig, glances: bool = True) -> str:
    """Runs with equal keys can share one batched model: the config without the fields that
    may differ per run (:data:`PER_RUN`, and the model's ``truncate_bptt``; a beta of 0 skips
    the REINFORCE term, so it is its own shape). ``glances=False``: runs of other glance counts
    too (``model.glances``, 2 or more; one glance, with no pose to choose, stays a shape of its
    own): the model steps as many glances as its longest run, and a run's glances after its
    last are computed, left out of its loss and its evaluation, and draw nothing from its
    generators (:meth:`BatchedRuns._forward`). That pays where a step costs its kernel launches
    (a GPU), not on a CPU (docs/batched.md)."""
    d = config.to_dict()
    for name in PER_RUN:
        d.pop(name)
    d["model"].pop("truncate_bptt")  # the core's state detached per run (StackedHam.truncate)
    if not glances and config.model.glances > 1:
        d["model"].pop("glances")
    d["beta_zero"] = config.beta == 0
    return json.dumps(d, sort_keys=True)


def _same_run(a: TrainConfig, b: TrainConfig) -> bool:
    """Whether ``a`` and ``b`` are one run's config (equal but for ``steps``)."""
    da, db = a.to_dict(), b.to_dict()
    da.pop("steps")
    db.pop("steps")
    return da == db


def check_batchable(config: TrainConfig) -> None:
    """Refuse, with one line, what the batched trainer does not handle."""
    if config.learner != "hybrid":
        raise HamError(
            f"learner {config.learner!r} cannot be batched; accepted: hybrid "
            "(train it with ham train or --executor local)"
        )
    if config.env is not None:
        raise HamError(
            f"env {config.env.env!r} cannot be batched; accepted: the haptic world "
            "(train it with ham train or --executor local)"
        )
    if config.model.core not in ("lstm", "mlp"):
        raise HamError(
            f"core {config.model.core!r} cannot be batched; accepted: lstm, mlp "
            "(train it with ham train or --executor local)"
        )
    if config.model.policy not in ("learned", "random"):
        raise HamError(
            f"policy {config.model.policy!r} cannot be batched; accepted: learned, random "
            "(train it with ham train or --executor local)"
        )
    if config.model.encoders != "shared":
        raise HamError(
            f"encoders {config.model.encoders!r} cannot be batched; accepted: shared (train it "
            "with ham train or --executor local)"
        )
    if config.model.stay_gate:
        raise HamError(
            "stay_gate cannot be batched; accepted: no --stay-gate (train it with ham train or "
            "--executor local)"
        )
    if config.model.first_glance not in ("random", "learned"):
        raise HamError(
            f"first_glance {config.model.first_glance!r} cannot be batched; accepted: random, "
            "learned (train it with ham train or --executor local)"
        )
    if config.model.first_glance == "learned" and config.model.glances == 1:
        raise HamError(
            "first_glance 'learned' with 1 glance cannot be batched; accepted: 2 or more "
            "glances (train it with ham train or --executor local)"
        )
    if config.model.pose_dims != ("x", "phi") or config.model.height_input:
        raise HamError(
            f"pose dims {','.join(config.model.pose_dims)}"
            f"{' with the height input' if config.model.height_input else ''} cannot be "
            "batched; accepted: the paper's x,phi without height (train it with ham train or "
            "--executor local)"
        )
    if config.object_pose.enabled:
        raise HamError(
            "a random object pose cannot be batched; accepted: none (train it with ham train "
            "or --executor local)"
        )


def _lr_scales(run: Run, params: dict[str, torch.nn.Parameter]) -> dict[str, float]:
    """Each weight's learning-rate scale in ``run``'s optimizer (its parameter group's
    ``lr_scale``: the location network's ``policy_lr_scale``), by the weight's name."""
    scale = {id(p): g.get("lr_scale", 1.0) for g in run.optimizer.param_groups for p in g["params"]}
    return {n: scale[id(p)] for n, p in params.items()}


def _keep_freed_memory() -> None:
    """Ask glibc to keep freed memory for reuse (mmap threshold 32 MiB, trim at 512 MiB).

    By default a freed block of more than 128 KiB, or memory at the top of the heap, goes back
    to the operating system, and the next step's tensors of the same size fault every page back
    in: tens of thousands of page faults per batched step (several ms per run-step on this
    CPU). Process-wide and idempotent; a no-op where the C library is not glibc."""
    global _MALLOPT_DONE
    if _MALLOPT_DONE:
        return
    _MALLOPT_DONE = True
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD (glibc's largest)
        libc.mallopt(-1, 512 << 20)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        pass


_MALLOPT_DONE = False
# episodes of a run per pass of a batched evaluation (eight batches of 64): products this deep
# run at the CPU's peak; deeper passes lose more in the elementwise parts, whose tensors
# outgrow the caches (measured at 10 glances, 10 runs: 64 rows 880 ms per run, 256-1024 rows
# 580-640 ms, 2048 rows 710-810 ms)
_EVAL_ROWS = 512
#: a run's evaluation draws kept between evaluations up to this size (the paper's protocol at
#: 10 glances: about 1.5 MB a run); larger ones are drawn anew each time
_KEPT_DRAWS_BYTES = 16 * 2**20
_FUSED_SGD = getattr(torch, "_fused_sgd_", None)
# elements a run's tensor must come in multiples of to be updated over the whole stack (a
# multiple of every CPU's vector width): no element of it falls in the fused kernel's scalar tail
_WHOLE_VECTORS = 64
_GRAPH_WARMUP = 2  # eager steps of a new stack before its step is captured as a CUDA graph


@dataclass
class _GraphState:
    """A stack's CUDA graph (:meth:`BatchedRuns._graphed_step`): its eager warm-up steps so
    far, the replay once captured, and the rates it reads (one per update: ``rate_keys``, its
    (run, scale) pairs), filled before each replay (on a GPU through ``pinned`` memory)."""

    warm: int = 0
    replay: Callable[[], torch.Tensor] | None = None
    rate_keys: list[tuple] | None = None
    rates: torch.Tensor | None = None
    pinned: torch.Tensor | None = None


def _capturing() -> bool:
    """Whether a CUDA graph is being captured (its kernels are recorded, not run)."""
    return torch.cuda.is_available() and torch.cuda.is_current_stream_capturing()


def _grouped(items, key) -> dict:
    """``items`` by ``key(item)``, in order: ``{key: [item, ...]}``."""
    out: dict = {}
    for item in items:
        out.setdefault(key(item), []).append(item)
    return out


def _own_glances(episode: list, glances: int) -> list:
    """The episode tensors ``(objects, locations, logits, baselines, mu, sigma,
    first_baseline)`` of runs of ``glances`` glances in a model stepping more (runs of other
    glance counts): their first ``glances`` along axis 1 (of the policy's ``mu`` and ``sigma``
    ``glances - 1``, or ``glances`` with a learned first glance)."""
    objects, locations, logits, baselines, mu, sigma, first = episode
    chosen = glances if first is not None else glances - 1
    policy = [None if t is None else t[:, :chosen] for t in (mu, sigma)]
    return [objects, locations[:, :glances], logits[:, :glances], baselines[:, :glances], *policy,
            first]  # fmt: skip


def _executed(runs: list[Run], q: torch.Tensor, glancing: list[bool], noise=None) -> torch.Tensor:
    """Each run's executed poses ``(N, B, 2)`` for its chosen poses ``q``
    (:meth:`HapticEnv.executed`): with pose noise drawn from its own env's current generator,
    as its single run draws them, or taken from ``noise`` ``(N, B, 2)`` (drawn ahead); a run
    past its last glance (``glancing`` false) draws nothing. ``q`` itself without noise."""
    if all(r.env.pose_noise == 0 for r in runs):
        return q
    return torch.stack([
        r.env.executed(q[k], None if noise is None else noise[k]) if glancing[k] else q[k]
        for k, r in enumerate(runs)
    ])  # fmt: skip


def _pressure(
    runs: list[Run], flat_objects: torch.Tensor, q: torch.Tensor, const, spreads=None
) -> torch.Tensor:
    """The glances ``(N, B, N^2)`` of ``runs`` at executed poses ``q (N, B, 2)``
    (:func:`_executed`) on objects ``flat_objects (N * B,)``, as each run's
    :meth:`HapticEnv.glance` gives them: one lookup for all runs (their envs share the glance
    source), each run's rows read out as its env reads them (:meth:`HapticEnv.read_out`: its
    normalization and, in training, its batch's spreads: ``spreads``, each run's
    :attr:`HapticEnv.batch_spreads`). ``const``: :meth:`BatchedRuns._const`."""
    n, rows = q.shape[0], q.shape[1]
    spreads = spreads or [None] * n
    kinds = _grouped(range(n), lambda k: (runs[k].env.normalization, None if spreads[k] is None
                                          else runs[k].env.augment_sigma))  # fmt: skip
    if len(kinds) == 1 and spreads[0] is None:
        return runs[0].env.glance(flat_objects, q.reshape(-1, 2), exact=True).view(n, rows, -1)
    raw, _ = runs[0].env.source.glance(flat_objects, q.reshape(-1, 2))
    raw = raw.view(n, rows, *raw.shape[1:])
    out = None
    for ks in kinds.values():
        idx = const(ks)
        s = None if spreads[ks[0]] is None else torch.cat([spreads[k] for k in ks])
        part = runs[ks[0]].env.read_out(raw.index_select(0, idx).flatten(0, 1), s)
        part = part.view(len(ks), rows, -1)
        out = part.new_empty(n, rows, part.shape[2]) if out is None else out
        out.index_copy_(0, idx, part)
    return out


class BatchedRuns:
    """N :class:`Run` s of one shape, their weights stacked; :meth:`train` trains them all."""

    def __init__(
        self,
        runs: list[Run],
        outs: list[Path],
        stop_at_perfect: bool = False,
        stopped: dict[int, int] | None = None,
        cuda_graph: bool = False,
    ) -> None:
        self.runs, self.outs = list(runs), [Path(o) for o in outs]
        source_commit()  # the code these runs start with, named in their timing.json at the end
        self.stop_at_perfect = stop_at_perfect
        self.results: dict[int, dict | str] = {}  # run index -> metrics, or the error line
        self.stopped: dict[int, int] = dict(stopped or {})  # run index -> the step it stopped
        self._overflowed: dict[int, str] = {}  # run index -> its Adam update's overflow
        self.active = [
            i for i in range(len(self.runs)) if not self._done(i) and i not in self.stopped
        ]
        _keep_freed_memory()
        # its config and initial state only; the longest run's (runs of other glance counts)
        self._template = max(self.runs, key=lambda r: r.config.model.glances).agent
        self._net = StackedHam(self._template.config)
        self._names = [n for n, _ in self.runs[0].agent.named_parameters()]
        self._params = [dict(r.agent.named_parameters()) for r in self.runs]
        # SGD (the paper's) is stepped for all runs at once; Adam by each run's own optimizer
        self._sgd = self.runs[0].config.optimizer == "sgd"
        if cuda_graph and not (self._sgd and _FUSED_SGD is not None):
            raise HamError(f"optimizer {self.runs[0].config.optimizer!r} with a CUDA graph; "
                           "accepted: sgd (each run's own Adam steps apart)")  # fmt: skip
        online = [r for r in self.runs if isinstance(r.env.source, OnlineSource)]
        if cuda_graph and online:  # its glance iterates to each contact, asking the host
            raise HamError(f"a CUDA graph on {online[0].env.source.description}; accepted: "
                           "runs on a glance table (--table), or the eager step (no "
                           "--cuda-graph)")  # fmt: skip
        if cuda_graph and any(r.config.pose_noise > 0 for r in self.runs):
            raise HamError("pose_noise with a CUDA graph (not yet run on a GPU); accepted: "
                           "pose_noise = 0, or the eager step (no --cuda-graph)")  # fmt: skip
        # with a CUDA graph (_graphed_step): its state for the current stack, {} when new
        self.cuda_graph = cuda_graph
        self._graph_state: _GraphState | None = None
        self._lr_scale = [_lr_scales(r, p) for r, p in zip(self.runs, self._params, strict=True)]
        self._checked = False
        # the active runs' loss and reward summed since their last evaluation (their train
        # loss and reward in the evaluation's record), and the last step's numbers (step())
        self.sums = torch.zeros(2, len(self.active), device=self.runs[0].env.device)
        self.numbers = self.sums.new_zeros(5, len(self.active))
        self._consts: dict[tuple, torch.Tensor] = {}  # _const's tensors
        self._kept_draws: dict[int, tuple] = {}  # run index -> its evaluation draws
        self.stream: torch.cuda.Stream | None = None  # its own CUDA stream (train_groups)
        self._t_train, self._n_train = 0.0, 0  # the time in launch and land, the steps
        if self.active:
            self._stack()

    # ------------------------------------------------------------------ stacked weights
    def _stack(self) -> None:
        """Stack the active runs' weights (and SGD momentum buffers) and make each run's
        parameters (and its optimizer's buffers) views of the stack: the run's own optimizer
        state and checkpoint stay as ``ham train`` writes them."""
        self.stacked: dict[str, torch.Tensor] = {}
        self.buffers: dict[str, torch.Tensor] = {}
        params = [self._params[i] for i in self.active]
        for name in self._names:
            big = torch.stack([p[name].detach() for p in params])
            for k, p in enumerate(params):
                p[name].data = big[k]
            self.stacked[name] = big.detach().requires_grad_()
            if self._sgd:
                # .get: the optimizer's state is a defaultdict, and a run without momentum
                # keeps no entries (its checkpoint is the single run's)
                states = [self.runs[i].optimizer.state.get(self._params[i][name], {})
                          for i in self.active]  # fmt: skip
                if any("momentum_buffer" in st for st in states):
                    # a run without one yet starts from zeros: 0 * m + g is exactly the
                    # optimizer's first buffer (a copy of g)
                    self._new_buffer(name, [st.get("momentum_buffer") for st in states])
        self._graph_state = _GraphState() if self.cuda_graph else None  # a new stack: a new graph
        truncate = [self.runs[i].config.model.truncate_bptt for i in self.active]
        if all(t == self._template.config.truncate_bptt for t in truncate):
            self._net.truncate = None  # the stacked model's config says it for all
        else:  # the active runs' choices, as the stack's run axis
            device = next(iter(self.stacked.values())).device
            self._net.truncate = torch.tensor(truncate, device=device).view(-1, 1, 1)

    def _const(self, values: list, dtype: torch.dtype | None = None) -> torch.Tensor:
        """``torch.tensor(values)`` on the group's device, made once: a step makes no tensor of
        Python values (on a GPU each is a copy from the host, and none may be made in a
        captured graph)."""
        key = (tuple((type(v), v) for v in values), dtype)  # (True,) == (1,) but not its type
        if key not in self._consts:
            self._consts[key] = torch.tensor(values, dtype=dtype, device=self.sums.device)
        return self._consts[key]

    def _new_buffer(self, name: str, bufs: list[torch.Tensor | None]) -> torch.Tensor:
        big = torch.stack([torch.zeros_like(self.stacked[name][0]) if b is None else b.detach()
                           for b in bufs])  # fmt: skip
        for k, i in enumerate(self.active):
            if self.runs[i].config.momentum != 0:  # SGD keeps no buffers without momentum
                self.runs[i].optimizer.state[self._params[i][name]]["momentum_buffer"] = big[k]
        self.buffers[name] = big
        return big

    def _drop(self, gone: list[int]) -> None:
        """Take runs out of the group (finished, diverged, stopped); the others go on."""
        keep = [k for k, i in enumerate(self.active) if i not in gone]
        self.active = [self.active[k] for k in keep]
        self.sums = self.sums[:, keep]
        for i in gone:  # its own compact copy of the weights and buffers, apart from the stack
            for p in self.runs[i].agent.parameters():
                p.data = p.data.clone()
            for st in self.runs[i].optimizer.state.values():
                if "momentum_buffer" in st:
                    st["momentum_buffer"] = st["momentum_buffer"].clone()
        if self.active:
            self._stack()

    def _sgd_step(self, runs: list[Run], grads: dict) -> None:
        """``torch.optim.SGD``'s update (momentum, Nesterov or not, no dampening or weight decay)
        of every active run over the stacked tensors: one fused pass per learning rate and
        momentum (PyTorch's ``_fused_sgd_``: the foreach optimizer's numbers to the last bit of
        the momentum buffer) instead of N optimizers looping over their parameters. Runs of one
        rate and momentum (the usual case: one schedule, one step) are updated as whole stacked
        tensors (but each run's small tensors apart: a run's numbers do not depend on which runs
        share its model), others run by run. A run whose loss was not finite is updated too (no host
        sync before the update); it leaves the group after the step, its update unused."""
        settings = self._settings(runs)
        if self._whole(runs, settings):
            parts = [(slice(None), 0)]
        else:
            parts = [(k, k) for k in range(len(runs))]
        if any(m != 0 for _, m, _, _ in settings):
            for name in grads:
                if name not in self.buffers:
                    self._new_buffer(name, [None] * len(runs))
        calls = []  # (idx, run, scale, names): one update each
        for idx, k in parts:
            by_scale: dict[float, list[str]] = {}
            for name in grads:
                by_scale.setdefault(settings[k][3][name], []).append(name)
            calls += [(idx, k, scale, names) for scale, names in by_scale.items()]
        rates = self._rate_tensor(settings, [(k, scale) for _, k, scale, _ in calls])

        # a small tensor (a 2-element bias) run by run: the fused kernel rounds the elements
        # of its vector loop (a fused multiply-add) and of its scalar tail differently, so over
        # a whole stack a run's small tensors would round by where they lie in it, that is by
        # which runs share its model; a tensor of whole vectors per run has no tail
        # (docs/batched.md, "A run's numbers and its batch-mates")
        def views(ts: dict, n: str, idx) -> list[torch.Tensor]:
            t = ts[n][idx]
            if isinstance(idx, slice) and t[0].numel() % _WHOLE_VECTORS:
                return list(t.unbind(0))
            return [t]

        with torch.no_grad():
            for j, (idx, k, scale, names) in enumerate(calls):
                lr, m, nesterov, _ = settings[k]
                ps = [v for n in names for v in views(self.stacked, n, idx)]
                gs = [v for n in names for v in views(grads, n, idx)]
                if m == 0 and rates is None:  # the optimizer keeps no buffers
                    torch._foreach_add_(ps, gs, alpha=-(lr * scale))
                elif _FUSED_SGD is not None:
                    # zero-initialized buffers: 0 * m + g is exactly the first buffer; with a
                    # graph the rate is read from the device (its replays' rates)
                    bufs = [v for n in names for v in views(self.buffers, n, idx)] if m else []
                    _FUSED_SGD(ps, gs, bufs,
                               weight_decay=0.0, momentum=m,
                               lr=lr * scale if rates is None else rates[j], dampening=0.0,
                               nesterov=nesterov, maximize=False,
                               is_first_step=False)  # fmt: skip
                else:  # torch.optim.SGD's foreach steps
                    bs = [v for n in names for v in views(self.buffers, n, idx)]
                    torch._foreach_mul_(bs, m)
                    torch._foreach_add_(bs, gs)
                    ds = torch._foreach_add(gs, bs, alpha=m) if nesterov else bs
                    torch._foreach_add_(ps, ds, alpha=-(lr * scale))

    def _settings(self, runs: list[Run]) -> list[tuple]:
        """Each run's SGD at this step: (rate, momentum, Nesterov, its weights' rate scales)."""
        return [(r.config.learning_rate(r.step), r.config.momentum, r.config.nesterov,
                 self._lr_scale[i]) for r, i in zip(runs, self.active, strict=True)]  # fmt: skip

    def _whole(self, runs: list[Run], settings: list[tuple]) -> bool:
        """Whether one update steps the whole stack: every run at one rate and momentum. A
        graph replays one choice, so there it is made of the runs' schedules and steps
        (equal schedules at equal steps give equal rates at every step)."""
        if self._graph_state is None:
            return all(v == settings[0] for v in settings)
        schedule = [(r.step, r.config.lr, r.config.lr_decay, r.config.lr_step, r.config.lr_min,
                     *v[1:3], tuple(v[3].items())) for r, v in zip(runs, settings, strict=True)]  # fmt: skip
        return all(v == schedule[0] for v in schedule)

    def _rate_tensor(self, settings: list[tuple], keys: list[tuple]) -> torch.Tensor | None:
        """With a graph (:meth:`_graphed_step`): the updates' rates, one per (run, scale) of
        ``keys``, as a tensor the step reads on the device; filled here, except while the
        step is captured (each replay's rates are filled before it, :meth:`_fill_rates`).
        ``None`` without a graph: the rates are numbers."""
        state = self._graph_state
        if state is None:
            return None
        if state.rate_keys != keys:
            # float32 on a GPU (the fused kernel reads it so), float64 on a CPU (read as a
            # double there: the numbers of the rates given as numbers, to the bit)
            dtype = torch.float64 if self.sums.device.type == "cpu" else torch.float32
            state.rate_keys = keys
            state.rates = torch.zeros(len(keys), dtype=dtype, device=self.sums.device)
        if not _capturing():
            self._fill_rates(settings)
        return state.rates

    def _fill_rates(self, settings: list[tuple]) -> None:
        state = self._graph_state
        rates = state.rates
        values = torch.tensor([settings[k][0] * scale for k, scale in state.rate_keys],
                              dtype=rates.dtype)  # fmt: skip
        if rates.device.type != "cuda":
            rates.copy_(values)
            return
        # through pinned memory: a copy from pageable memory would wait for the GPU to idle
        # (the step's flags were read, so the last copy from this buffer is done)
        if state.pinned is None or state.pinned.shape != rates.shape:
            state.pinned = torch.empty_like(values).pin_memory()
        state.pinned.copy_(values)
        rates.copy_(state.pinned, non_blocking=True)

    def _done(self, i: int) -> bool:
        return self.runs[i].step >= self.runs[i].config.steps

    # ------------------------------------------------------------------ one step of all runs
    def _forward(self, objects: torch.Tensor, spreads: list | None = None):
        """One episode of every active run: objects ``(N, B)`` (and each run's read-out
        ``spreads``, :func:`_pressure`) -> the stacked episode tensors."""
        runs = [self.runs[i] for i in self.active]
        n, batch = objects.shape
        own = [r.config.model.glances for r in runs]
        glances = max(own)  # a run's glances after its own last are left out of its loss
        stand_ins: dict[tuple, torch.Tensor] = {}  # made once a step, by shape and dtype

        def draws(drawing: list[bool], shape: tuple, dtype: torch.dtype) -> torch.Tensor:
            """Each drawing run's ``U[0, 1)`` draws from its own generator (as its single run
            draws them), a stand-in for a run past its last glance (which draws nothing)."""
            if not all(drawing) and (shape, dtype) not in stand_ins:
                stand_ins[shape, dtype] = torch.full(shape, 0.5, dtype=dtype,
                                                     device=objects.device)  # fmt: skip
            return torch.stack([torch.rand(shape, generator=r.policy_generator, dtype=dtype,
                                           device=objects.device) if d else stand_ins[shape, dtype]
                                for r, d in zip(runs, drawing, strict=True)])  # fmt: skip

        def kept(drawn: torch.Tensor, drawing: list[bool], q: torch.Tensor) -> torch.Tensor:
            """The drawn poses, a run past its last glance keeping its pose ``q``."""
            if all(drawing):
                return drawn
            return torch.where(self._const(drawing).view(-1, 1, 1), drawn.to(q.dtype), q)

        locations, logits, baselines, mus, sigmas = [], [], [], [], []
        first = self._first_glance(self.stacked, batch)
        if first is None:  # the first glance: random (the paper), transformed once for all runs
            u = draws([True] * n, (batch, 2), torch.float32)
            q, first_baseline = uniform_locations(batch, None, uniform=u), None
        else:  # chosen by the policy from tau_0 (first_glance "learned")
            mu0, sigma0, first_baseline = first
            mus.append(mu0)
            sigmas.append(sigma0)
            q = truncated_normal(mu0, sigma0, uniform=draws([True] * n, (batch, 2), torch.float64))
        state = None  # the core's initial state (LSTMCore's zeros)
        flat_objects = objects.reshape(-1)
        for s in range(glances):
            # one lookup of N * B glances: a glance depends only on its object and pose
            at = _executed(runs, q, [s < g for g in own])
            pressure = _pressure(runs, flat_objects, at, self._const, spreads)
            final = s == glances - 1
            state, lg, b, dist = self._net.glance(self.stacked, pressure, q, state, not final)
            locations.append(q)
            logits.append(lg)
            baselines.append(b)
            if final:
                break
            # a run past its last glance draws nothing (its generator as its single run's):
            # its pose stays where it was
            drawing = [s < g - 1 for g in own]
            if dist:
                mus.append(dist[0])
                sigmas.append(dist[1])
                # each run's draws as TruncatedGaussian.sample draws them, the inverse-CDF
                # transform once for all runs
                u = draws(drawing, tuple(dist[0].shape[1:]), torch.float64)
                q = kept(truncated_normal(dist[0], dist[1], uniform=u), drawing, q)
            else:  # the random policy (Uniform.sample's draws), transformed once for all runs
                u = draws(drawing, (batch, 2), torch.float32)
                q = kept(uniform_locations(batch, None, uniform=u), drawing, q)
        mu = torch.stack(mus, 1) if mus else None
        sigma = torch.stack(sigmas, 1) if sigmas else None
        return (
            torch.stack(locations, 1),
            torch.stack(logits, 1),
            torch.stack(baselines, 1),
            mu,
            sigma,
            first_baseline,
        )

    def _first_glance(self, p: dict, batch: int):
        """With ``first_glance = "learned"`` (:meth:`HapticAttentionModel.first_glance`): the
        location network's ``(mu, sigma)`` and the baseline at ``tau_0 = 0``, ``(N, B, 2)`` twice
        and ``(N, B)``; ``None`` for a random first glance. At ``tau_0 = 0`` each head's output
        is its bias: read straight from the biases, whose gradient autograd leaves in their
        ``.grad`` (:meth:`_first_grads`)."""
        if not self._template.chooses_first_glance:  # (check_batchable refuses "own")
            return None
        c = self._template.config

        def out(name: str) -> torch.Tensor:  # a head's output at tau_0: its bias, or 0
            bias = p.get(name + ".bias")
            if bias is not None:
                return bias
            weight = p[name + ".weight"]
            return weight.new_zeros(weight.shape[:2])

        mu = torch.tanh(out("location.mu"))
        s = out("location.sigma")
        sigma = F.softplus(s) if c.std_activation == "softplus" else torch.sigmoid(s)
        n = mu.shape[0]
        return (
            mu[:, None].expand(n, batch, -1),
            (sigma + c.sigma_min)[:, None].expand(n, batch, -1),
            out("baseline.dense").expand(n, batch),
        )

    def _first_grads(self, grads: dict) -> None:
        """The gradients of the heads' biases through the learned first glance (autograd's, in
        the stacked leaves' ``.grad``) added to the layers' ``grads``, and the leaves cleared."""
        for name in _FIRST_BIASES:
            leaf = self.stacked.get(name)
            if leaf is not None and leaf.grad is not None:
                grads[name] = grads[name] + leaf.grad
                leaf.grad = None

    def _losses(self, objects, locations, logits, baselines, mu, sigma, first_baseline):
        """Each active run's hybrid loss (:func:`ham.learn.hybrid_loss.hybrid_loss`, mapped
        over the runs): ``(total, reward, classification, reinforce, baseline)``, each ``(N,
        ...)``. Runs of other loss reductions, classified or rewarded glances or discounts are
        mapped apart (code, not a number), each with its own beta, and so are runs of other
        glance counts, each over its own glances (:func:`_own_glances`)."""
        runs = [self.runs[i] for i in self.active]
        kinds = _grouped(range(len(runs)), lambda k: (runs[k].config.classification_reduction,
                                                      runs[k].config.reinforce_reduction,
                                                      runs[k].config.classification_glances,
                                                      runs[k].config.reward_glances,
                                                      runs[k].config.reward_discount,
                                                      runs[k].config.glance_reduction,
                                                      runs[k].config.model.glances))  # fmt: skip
        args = (objects, locations, logits, baselines, mu, sigma, first_baseline)
        if len(kinds) == 1:
            (((*reductions, glances), ks),) = kinds.items()
            return self._mapped_loss(glances, reductions, [runs[k] for k in ks], *args)
        out = [None] * len(runs)
        for (*reductions, glances), ks in kinds.items():
            idx = self._const(ks)
            part = _own_glances([None if a is None else a.index_select(0, idx) for a in args],
                                glances)  # fmt: skip
            parts = self._mapped_loss(glances, reductions, [runs[k] for k in ks], *part)
            for j, k in enumerate(ks):
                out[k] = [x[j] for x in parts]
        return tuple(torch.stack(xs) for xs in zip(*out, strict=True))

    def _mapped_loss(self, glances, reductions, runs, objects, locations, logits, baselines, mu,
                     sigma, first_baseline):  # fmt: skip
        """:func:`hybrid_loss` of ``runs`` (one kind of loss: its reductions, the glances it
        classifies and rewards, its discount), mapped over them."""
        # one beta for the runs: the number itself; else each run's, mapped with its episode
        betas = [r.config.beta for r in runs]
        beta = self._const(betas, logits.dtype)
        one = len(set(betas)) == 1
        chosen = glances if first_baseline is not None else glances - 1  # the policy's poses

        def loss(objects, locations, logits, baselines, beta, mu=None, sigma=None, first=None):
            if chosen == 0:
                policy = None
            elif mu is None:
                policy = Uniform((chosen, objects.shape[0]), objects.device)
            else:
                policy = TruncatedGaussian(mu, sigma)
            episode = Episode(objects, locations, logits, baselines, policy, first)
            h = hybrid_loss(episode, betas[0] if one else beta, *reductions)
            return h.total, h.reward, h.classification, h.reinforce, h.baseline

        # the optional tensors by name: vmap maps tensors, not None
        given = {k: v for k, v in (("mu", mu), ("sigma", sigma), ("first", first_baseline))
                 if v is not None}  # fmt: skip

        def mapped(objects, locations, logits, baselines, beta, *rest):
            return loss(objects, locations, logits, baselines, beta,
                        **dict(zip(given, rest, strict=True)))  # fmt: skip

        return torch.vmap(mapped)(objects, locations, logits, baselines, beta, *given.values())

    def step(self) -> list[tuple[int, int]]:
        """One training step of every active run (:func:`ham.learn.train.train_step` for N).

        Returns ``(run index, column)`` of the runs that stepped: column ``column`` of
        :attr:`numbers` ``(5, N)`` holds the run's loss, mean reward and loss parts
        (classification, reinforce, baseline), detached on the device, and its loss and mean
        reward are added to its running sums since its last evaluation (:attr:`sums`). A run
        whose loss or weights are not finite leaves the group with its error recorded."""
        self.launch()
        return self.land()

    def launch(self) -> None:
        """A step of every active run sent to the device; nothing is read back until
        :meth:`land` (so that several groups' steps can overlap on a GPU: :func:`train_groups`)."""
        t0 = time.perf_counter()
        runs = [self.runs[i] for i in self.active]
        for r in runs:  # as train_step: the run's optimizer (its checkpoint) holds its rates
            for group in r.optimizer.param_groups:
                group["lr"] = r.config.learning_rate(r.step) * group.get("lr_scale", 1.0)
        with self._on_stream():  # all of a group's work on its stream: no race with another's
            flags = self._graphed_step(runs) if self.cuda_graph else self._device_step(runs)
        self._launched = (runs, flags)
        self._t_train += time.perf_counter() - t0

    def land(self) -> list[tuple[int, int]]:
        """The launched step's flags read back (its one sync) and its runs' steps counted; a run
        whose loss or weights are not finite leaves the group. Returns :meth:`step`'s value."""
        with self._on_stream():  # a run leaving restacks the weights: on the group's stream
            return self._land()

    def _land(self) -> list[tuple[int, int]]:
        runs, flags = self._launched
        loss_ok, weights_ok = flags.tolist()
        failed, out = [], []
        for k, r in enumerate(runs):
            i = self.active[k]
            if loss_ok[k]:
                r.step += 1
            try:
                if i in self._overflowed:
                    raise HamError(self._overflowed.pop(i))
                if not loss_ok[k]:
                    check_loss(r, self.numbers[0, k])
                if not weights_ok[k]:
                    check_weights(r)  # the message, with the first weight named
            except HamError as exc:
                self.results[i] = str(exc)
                failed.append(i)
                continue
            out.append((i, k))
        if failed:
            self._drop(failed)
        return out

    def _graphed_step(self, runs: list[Run]) -> torch.Tensor:
        """:meth:`_device_step` captured once per stack as a CUDA graph and replayed: each step
        then launches its ~1,400 kernels (10 glances) as one graph instead of one by one from
        Python. The first steps of a new stack run eagerly (warm-up, on a side stream); a run
        leaving the group makes a new stack and so a new graph. Every run's two generators are
        registered with the graph, so a replay draws what the eager step would. On a CPU
        (no graphs) the device step is called where a graph would be replayed: the same
        protocol, checked by the tests against the eager step, to the bit."""
        state = self._graph_state
        if state.replay is not None:
            self._fill_rates(self._settings(runs))
            return state.replay()
        cuda = self.sums.device.type == "cuda"
        if state.warm < _GRAPH_WARMUP:
            state.warm += 1
            if not cuda:
                return self._device_step(runs)
            side = torch.cuda.Stream()  # as torch.cuda.graphs' whole-network example warms up
            side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(side):
                flags = self._device_step(runs)
            torch.cuda.current_stream().wait_stream(side)
            return flags
        if not cuda:
            state.replay = lambda: self._device_step(runs)
        else:
            graph = torch.cuda.CUDAGraph()
            for r in runs:  # each replay advances them by the draws of one step
                graph.register_generator_state(r.env.generator)
                graph.register_generator_state(r.policy_generator)
            with torch.cuda.graph(graph):  # records the step; runs nothing
                flags = self._device_step(runs)

            def replay() -> torch.Tensor:
                graph.replay()
                return flags

            state.replay = replay
        return self._graphed_step(runs)

    def _device_step(self, runs: list[Run]) -> torch.Tensor:
        """The step's work on the device, ``(2, N)`` flags back: each run's loss finite, its
        weights finite after the update. With SGD it asks the host nothing (no sync, no tensor
        made from Python values: the group's constants are made once, :meth:`_const`), so on a
        GPU it could be captured as one graph; each run's own Adam needs the flags first."""
        objects = torch.stack([r.env.sample_objects() for r in runs])
        spreads = [r.env.batch_spreads for r in runs]  # drawn with the objects (spread_augment)
        spreads = None if all(t is None for t in spreads) else spreads
        self._net.begin(self.stacked)
        totals, rewards, *parts = self._losses(objects, *self._forward(objects, spreads))
        if not self._checked:  # a weight the stacked layers skip would silently never train
            unused = set(self._names) - self._net.used
            if self._template.config.glances == 1:  # no glance is chosen by the policy
                unused = {n for n in unused if not n.startswith("location.")}
            if unused:
                raise HamError(f"the batched layers do not read the weights {sorted(unused)}; "
                               "train this model with ham train or --executor local")  # fmt: skip
            self._checked = True
        finite = torch.isfinite(totals)
        # a run whose loss is not finite takes no part in the backward (its gradient is zeros)
        torch.where(finite, totals, torch.zeros_like(totals)).sum().backward()
        grads = self._net.grads()  # None of a layer unused (one glance: the location heads)
        self._first_grads(grads)
        if self._sgd:
            self._sgd_step(runs, grads)
        else:
            for k, ok in enumerate(finite.tolist()):
                if ok:
                    r, params = runs[k], self._params[self.active[k]]
                    for name, p in params.items():
                        p.grad = grads[name][k] if name in grads else None
                    try:
                        r.optimizer.step()
                    except RuntimeError as exc:  # an update beyond float32: this run diverged
                        diverged = overflowed(r, exc)
                        if diverged is None:
                            raise
                        self._overflowed[self.active[k]] = str(diverged)
                    for p in params.values():
                        p.grad = None
        with torch.no_grad():
            # the weights of all runs in one reduction, as check_weights does
            sums = torch.stack([v.reshape(len(runs), -1).sum(1) for v in self.stacked.values()])
            self.numbers = torch.stack([totals, rewards.mean(-1), *parts]).detach()
            self.sums += self.numbers[:2]
            return torch.stack([finite, torch.isfinite(sums.sum(0))])

    # ------------------------------------------------------------------ evaluation
    @torch.no_grad()
    def evaluate(self, idx: list[int]) -> list[EvalResult]:
        """:func:`ham.learn.evaluation.evaluate` of the runs ``idx`` (their config's
        ``eval_batches``, ``eval_policy`` and seed ``stream_seed(seed, 2)``), all at once.

        Every run's poses come from its own generator in the order the single evaluation draws
        them (per batch: the first glance, then each later glance unless the policy's mode is
        taken); drawn first, they let up to :data:`_EVAL_ROWS` episodes of a run (many
        evaluation batches: each batch is independent of the others) go through each stacked
        layer at once. The counts are the single evaluation's; sums of floats (path length,
        modes) to float tolerance."""
        # runs evaluated alike go through the layers at once
        kinds = _grouped(idx, lambda i: (self.runs[i].config.eval_batches,
                                         self.runs[i].config.eval_policy,
                                         self.runs[i].config.model.glances))  # fmt: skip
        if len(kinds) > 1:
            done = {i: res for sub in kinds.values()
                    for i, res in zip(sub, self.evaluate(sub), strict=True)}  # fmt: skip
            return [done[i] for i in idx]
        runs = [self.runs[i] for i in idx]
        c, env = runs[0].config, runs[0].env
        n, batch, batches, glances = len(runs), env.batch_size, c.eval_batches, c.model.glances
        device, k = env.device, env.n_objects
        learned = c.model.policy == "learned"
        greedy = learned and c.eval_policy == "mean"  # the random policy has no mode: samples
        if idx == self.active:
            p = {name: t.detach() for name, t in self.stacked.items()}
        else:
            p = {name: torch.stack([self._params[i][name].detach() for i in idx])
                 for name in self._names}  # fmt: skip
        later = 0 if greedy else glances - 1  # draws per batch after the first glance's
        dtype = torch.float64 if learned else torch.float32  # truncated_normal's, Uniform's
        # the first glance: random (Uniform's draws), or the policy's from tau_0 (its mode or
        # truncated_normal's draws)
        chosen = self._first_glance(p, 1)
        first_dtype = torch.float32 if chosen is None else torch.float64
        want_first = not (chosen is not None and greedy)
        first, draws, noise = self._eval_draws(idx, later, dtype, first_dtype, want_first)
        correct = torch.zeros(n, glances, device=device)
        accumulated = torch.zeros(n, glances, device=device)
        confusion = torch.zeros(n * glances * k * k, dtype=torch.long, device=device)
        offsets = (torch.arange(n, device=device).view(-1, 1, 1) * glances
                   + torch.arange(glances, device=device).view(1, -1, 1)) * (k * k)  # fmt: skip
        counts = torch.arange(1, glances + 1, device=device).view(1, -1, 1, 1)
        mu_sum = torch.zeros(n, k, 2, device=device, dtype=torch.float64)
        n_obj = torch.zeros(k, device=device, dtype=torch.float64)
        path = torch.zeros(n, device=device, dtype=torch.float64)
        # pose_sums of the 2-D poses: count, sums and sums of squares per glance and object
        poses = torch.zeros(n, glances, k, 1 + 2 * 2, device=device, dtype=torch.float64)
        per = max(1, _EVAL_ROWS // batch)  # batches per pass
        for b0 in range(0, batches, per):
            b1 = min(batches, b0 + per)
            rows = (b1 - b0) * batch
            objects = torch.cat([env.balanced_objects(b) for b in range(b0, b1)])
            flat_objects = objects.expand(n, rows).reshape(-1)
            if chosen is None:
                q = first[:, b0:b1].reshape(n, rows, 2) * 2 - 1  # uniform_locations
            else:  # the learned first glance: the same distribution for every episode
                mu0, sigma0 = (t.expand(n, rows, -1) for t in chosen[:2])
                if greedy:
                    q = torch.nan_to_num(mu0).clamp(-1, 1)  # TruncatedGaussian.mode
                else:
                    u = first[:, b0:b1].reshape(n, rows, 2)
                    q = truncated_normal(mu0, sigma0, uniform=u)
            state = None  # the core's initial state
            locations, logits, mode = [], [], None
            for s in range(glances):
                at = (
                    q
                    if noise is None
                    else _executed(runs, q, [True] * n, noise[:, b0:b1, s].reshape(n, rows, 2))
                )
                pressure = _pressure(runs, flat_objects, at, self._const)
                final = s == glances - 1
                state, lg, _, dist = self._net.glance(p, pressure, q, state, not final, False)
                locations.append(q)
                logits.append(lg)
                if final:
                    break
                if learned:
                    mode = torch.nan_to_num(dist[0]).clamp(-1, 1)  # TruncatedGaussian.mode
                if greedy:
                    q = mode
                elif learned:
                    u = draws[:, b0:b1, s].reshape(n, rows, 2)
                    q = truncated_normal(dist[0], dist[1], uniform=u)
                else:
                    q = draws[:, b0:b1, s].reshape(n, rows, 2) * 2 - 1  # Uniform.sample
            logit = torch.stack(logits, 1)  # (N, S, rows, K)
            predicted = logit.argmax(-1)
            correct += (predicted == objects).sum(-1)
            confusion += torch.bincount((offsets + objects * k + predicted).flatten(),
                                        minlength=confusion.numel())  # fmt: skip
            averaged = logit.softmax(-1).cumsum(1) / counts
            accumulated += (averaged.argmax(-1) == objects).sum(-1)
            loc = torch.stack(locations, 1)  # (N, S, rows, 2): path_lengths per run
            path += (loc[:, 1:] - loc[:, :-1]).norm(dim=-1).sum(1).sum(-1).double()
            poses += pose_sums(loc, objects, k)
            if mode is not None:
                mu_sum.index_add_(1, objects, mode.double())
                n_obj += torch.bincount(objects, minlength=k)
        confusion = confusion.view(n, -1)
        return [eval_result(env, batches, correct[j], accumulated[j], confusion[j], mu_sum[j],
                            n_obj, path[j], poses[j]) for j in range(n)]  # fmt: skip

    def _eval_draws(
        self, idx: list[int], later: int, dtype: torch.dtype, first_dtype: torch.dtype,
        want_first: bool,
    ) -> tuple[torch.Tensor | None, torch.Tensor, torch.Tensor | None]:  # fmt: skip
        """The runs ``idx``'s evaluation draws, stacked: the uniforms of the first glance
        (``want_first``) and of the ``later`` glances, and the pose noise, each run's from its
        own generators in the order its single evaluation draws them (per batch: the first
        glance, then each later one; the noise per batch and glance). Those generators are
        seeded anew at every evaluation (stream 2, :meth:`HapticEnv.eval_noise_generator`), so
        a run's draws are the same each time: drawn once and kept (up to
        :data:`_KEPT_DRAWS_BYTES` a run), instead of one small draw per batch and glance at
        every evaluation (10,000 a group of 10 runs at 10 glances: on a GPU, launches)."""
        out = []
        for i in idx:
            r = self.runs[i]
            batches, batch, glances = (
                r.config.eval_batches,
                r.env.batch_size,
                r.config.model.glances,
            )
            key = (batches, batch, glances, later, dtype, first_dtype if want_first else None)
            kept = self._kept_draws.get(i)
            if kept is not None and kept[0] == key:
                out.append(kept[1])
                continue
            device = r.env.device
            g = torch.Generator(device=device)
            g.manual_seed(stream_seed(r.config.seed, 2))
            first = (
                torch.empty(batches, batch, 2, device=device, dtype=first_dtype)
                if want_first
                else None
            )
            draws = torch.empty(batches, later, batch, 2, device=device, dtype=dtype)
            for b in range(batches):
                if first is not None:
                    torch.rand(batch, 2, generator=g, device=device, dtype=first_dtype,
                               out=first[b])  # fmt: skip
                for s in range(later):
                    torch.rand(batch, 2, generator=g, device=device, dtype=dtype,
                               out=draws[b, s])  # fmt: skip
            noise = None  # its noise is never read without pose noise (HapticEnv.executed)
            if r.env.pose_noise > 0:
                noise = torch.empty(batches, glances, batch, 2, device=device)
                for b in range(batches):
                    gn = r.env.eval_noise_generator(b)
                    for s in range(glances):
                        torch.randn(batch, 2, generator=gn, device=device, out=noise[b, s])
            made = (first, draws, noise)
            size = sum(t.numel() * t.element_size() for t in made if t is not None)
            if size <= _KEPT_DRAWS_BYTES:
                self._kept_draws[i] = (key, made)
            out.append(made)
        first = torch.stack([m[0] for m in out]) if want_first else None
        draws = torch.stack([m[1] for m in out])
        noise = None
        if any(m[2] is not None for m in out):  # zeros for a run without pose noise
            shape = next(m[2].shape for m in out if m[2] is not None)
            noise = torch.stack([m[2] if m[2] is not None else draws.new_zeros(
                shape, dtype=torch.float32) for m in out])  # fmt: skip
        return first, draws, noise

    def _evaluate(self, due: list[tuple[int, float | None, float | None]]) -> dict[int, dict]:
        """Evaluate and record the runs ``due`` (run index, mean train loss and reward since
        the last evaluation), as :func:`ham.learn.train.evaluate_run`; their records by index."""
        if not due:
            return {}
        results = self.evaluate([i for i, _, _ in due])
        return {i: evaluate_run(self.runs[i], loss, reward, result)
                for (i, loss, reward), result in zip(due, results, strict=True)}  # fmt: skip

    # ------------------------------------------------------------------ the loop
    def train(self, progress: bool = False) -> list[dict | str]:
        """Train every run to its ``steps`` (:func:`ham.learn.train.train_loop` for N).

        Returns per run its metrics, or the one-line error that stopped it."""
        return train_groups([self], progress)[0]

    def start(self, progress: bool = False) -> None:
        """Before the first step: each run's directory and config, the first evaluation of the
        fresh runs, TensorBoard writers, the progress bar."""
        with self._on_stream():
            self._start(progress)

    def _start(self, progress: bool) -> None:
        from torch.utils.tensorboard import SummaryWriter
        from tqdm.auto import tqdm

        for r, out in zip(self.runs, self.outs, strict=True):
            out.mkdir(parents=True, exist_ok=True)
            write_json(out / CONFIG_FILE, r.config.to_dict())
        self._writers = writers = {}
        fresh = self._evaluate([(i, None, None) for i in self.active
                                if self.runs[i].step == 0 and not self.runs[i].history])  # fmt: skip
        for i, record in fresh.items():
            writers[i] = SummaryWriter(str(self.outs[i] / "tb"))
            log_evaluation(writers[i], record, self.runs[i].config.model.glances)
            self._save(i)
            self._maybe_stop(i)
        for i in list(self.active):
            r, out = self.runs[i], self.outs[i]
            if i not in writers:
                writers[i] = SummaryWriter(str(out / "tb"), purge_step=r.step or None)
        self.sums.zero_()  # each run's loss and reward since its last evaluation, and count
        self._counts = dict.fromkeys(self.active, 0)
        if self.stopped:
            self._drop([i for i in self.stopped if i in self.active])
        total = sum(self.runs[i].config.steps - self.runs[i].step for i in self.active)
        self._bar = tqdm(total=total, disable=not progress, unit="step",
                         desc=f"train x{len(self.active)}")  # fmt: skip
        self._t_train, self._n_train = 0.0, 0

    def finish(self) -> None:
        """After :meth:`launch`: the step read back (:meth:`land`), then its bookkeeping: the
        logs, the evaluations due (at once), the checkpoints, and the finished runs leave."""
        with self._on_stream():
            self._finish()

    def _finish(self) -> None:
        t0 = time.perf_counter()
        stepped = self.land()
        self._t_train += time.perf_counter() - t0
        self._n_train += 1
        self._bar.update(len(stepped))
        writers, counts = self._writers, self._counts
        finished, due = [], []
        logged = [(i, k) for i, k in stepped
                  if self.runs[i].step % self.runs[i].config.log_every == 0]  # fmt: skip
        numbers = self.numbers.tolist() if logged else None  # one read for all
        for i, k in logged:
            r, w = self.runs[i], writers[i]
            loss, reward, *parts = (row[k] for row in numbers)
            w.add_scalar("train/loss", loss, r.step)
            for name, x in zip(_PARTS, parts, strict=True):
                w.add_scalar(f"train/{name}", x, r.step)
            w.add_scalar("train/reward", reward, r.step)
            w.add_scalar("train/lr", r.optimizer.param_groups[0]["lr"], r.step)
        columns = {i: k for k, i in enumerate(self.active)}  # after the step's drops
        for i, _ in stepped:
            counts[i] += 1
            r = self.runs[i]
            if r.step % r.config.eval_every == 0 or r.step == r.config.steps:
                due.append(i)
        if due:
            sums = self.sums.tolist()
            due = [(i, sums[0][columns[i]] / counts[i], sums[1][columns[i]] / counts[i])
                   for i in due]  # fmt: skip
            self.sums[:, [columns[i] for i, _, _ in due]] = 0
            counts.update(dict.fromkeys([i for i, _, _ in due], 0))
        for i, record in self._evaluate(due).items():  # the due runs at once
            log_evaluation(writers[i], record, self.runs[i].config.model.glances)
            self._save(i)
            if self._maybe_stop(i):
                finished.append(i)
        for i, *_ in stepped:
            if self._done(i):
                finished.append(i)
        if finished:
            self._drop(sorted(set(finished)))

    def close(self) -> list[dict | str]:
        """After the last step: the writers closed, each run's timing.json; per run its
        metrics, or the one-line error that stopped it."""
        self._bar.close()
        for w in self._writers.values():
            w.close()
        # every run's metrics.json once more (not a diverged one's): a run that took no step
        # here (finished, its metrics.json lost) gets it back
        for i in range(len(self.runs)):
            if not isinstance(self.results.get(i), str):
                write_json(self.outs[i] / METRICS_FILE, self.metrics(i))
        environment = environment_record() if self._n_train else None
        for i in self._writers:
            if self._n_train:
                write_json(
                    self.outs[i] / TIMING_FILE,
                    {"steps_timed": self._n_train,
                     "ms_per_step": 1000 * self._t_train / self._n_train,
                     "batched_runs": len(self.runs), "torch_threads": torch.get_num_threads(),
                     "device": self.runs[i].config.device, "environment": environment},
                )  # fmt: skip
        return [self.results.get(i, None) or self.metrics(i) for i in range(len(self.runs))]

    def use_own_stream(self) -> None:
        """On a GPU, the group's work on a CUDA stream of its own from now on (after the work
        queued so far: its stacked weights), so that other groups' steps can overlap it."""
        if self.sums.device.type == "cuda":
            self.stream = torch.cuda.Stream(self.sums.device)
            self.stream.wait_stream(torch.cuda.current_stream(self.sums.device))

    def _on_stream(self):
        """The group's CUDA stream as the current one (:func:`train_groups`), else nothing."""
        return contextlib.nullcontext() if self.stream is None else torch.cuda.stream(self.stream)

    def _maybe_stop(self, i: int) -> bool:
        r = self.runs[i]
        if self.stop_at_perfect and r.best_accuracy >= 1.0 and not self._done(i):
            self.stopped[i] = r.step
            self._save(i)
            return True
        return False

    def metrics(self, i: int) -> dict:
        m = self.runs[i].metrics()
        if i in self.stopped:
            m[STOPPED_KEY] = self.stopped[i]
        return m

    def _save(self, i: int) -> None:
        """:func:`ham.learn.train._save`, with the weights copied out of the stack (a view
        would save the whole stack)."""
        state = self.runs[i].state_dict()
        state["model"] = {k: v.clone() for k, v in state["model"].items()}
        # (a copy: state_dict() shares the optimizer's own per-parameter dicts)
        state["optimizer"] = dict(state["optimizer"])
        state["optimizer"]["state"] = {
            k: {n: v.clone() if n == "momentum_buffer" else v for n, v in st.items()}
            for k, st in state["optimizer"]["state"].items()
        }
        atomic_write(self.outs[i] / CHECKPOINT_FILE, lambda p: torch.save(state, p))
        write_json(self.outs[i] / METRICS_FILE, self.metrics(i))


def train_groups(groups: list[BatchedRuns], progress: bool = False) -> list[list[dict | str]]:
    """Train several batched groups together, each to its runs' ``steps``: every round
    launches each group's step before reading any group's back (:meth:`BatchedRuns.launch`,
    :meth:`BatchedRuns.finish`), so that on a GPU the groups' steps, each on its own CUDA
    stream, can overlap. A group's numbers are its own (as trained alone). Returns each
    group's :meth:`BatchedRuns.train` value."""
    if len(groups) > 1:
        for g in groups:
            g.use_own_stream()
    started = []
    try:
        for g in groups:
            g.start(progress)
            started.append(g)
        live = [g for g in groups if g.active]
        while live:
            for g in live:
                g.launch()
            for g in live:
                g.finish()
            live = [g for g in live if g.active]
    finally:
        outcomes = [g.close() for g in started]
    return outcomes


# --------------------------------------------------------------------------- entry points
def _check_outs(configs: list[TrainConfig], outs: list[Path]) -> None:
    """One directory for each run of a batch, none shared."""
    if not configs:
        raise HamError("no runs to batch; accepted: one config or more")
    if len(configs) != len(outs):
        raise HamError(f"{len(configs)} configs but {len(outs)} directories; give one each")
    if len({str(o.resolve()) for o in outs}) != len(outs):
        raise HamError("two runs of one batch share a directory; give each its own")


def _open_runs(
    configs: list[TrainConfig], outs: list[Path], tables: dict | None = None
) -> list[Run]:
    """The runs of ``configs`` (one directory each in ``outs``, checked by
    :func:`train_batched`) with one shared glance source; a glance table's source is taken from
    ``tables`` when another batch opened it (batches trained together load each table once)."""
    for c in configs:
        check_batchable(c)
    keys = {shape_key(c, glances=False) for c in configs}
    if len(keys) > 1:
        raise HamError(
            "the batched runs differ in more than " + ", ".join(PER_RUN) + " and glances (2 or "
            "more); accepted: configs of one shape (a beta of 0 is a shape of its own)"
        )
    c0 = configs[0]
    device = torch.device(c0.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise HamError("device 'cuda' requested but CUDA is not available; use --device cpu")
    key = (str(c0.table), repr(c0.world), str(device))
    if tables is not None and c0.table is not None and key in tables:
        source, world = tables[key]
    else:
        source, world = make_source(c0.table, c0.world, device)
        if tables is not None and c0.table is not None:
            tables[key] = (source, world)
    check_model_fits(c0.model.pressure_dim, c0.model.n_objects, source)
    runs: list[Run] = []
    for c in configs:
        runs.append(Run.create(c, haptic_env(c, source, world, device)))
    return runs


@checked_arguments
def train_batched(
    configs: list[TrainConfig],
    outs: list[str | os.PathLike],
    *,
    stop_at_perfect: bool = False,
    progress: bool = False,
    cuda_graph: bool = False,
) -> list[dict | str]:
    """Train fresh runs ``configs`` into ``outs`` as one batch, or continue those whose
    directory holds a checkpoint (to the config's ``steps``). Returns per run its metrics (also
    in its metrics.json), or the one-line error that stopped it (NaN/inf). ``cuda_graph``: each
    step replayed as one CUDA graph (:meth:`BatchedRuns._graphed_step`; runs on a glance table)."""
    return train_batched_together(
        [(configs, outs)], stop_at_perfect=stop_at_perfect, progress=progress, cuda_graph=cuda_graph
    )[0]


@checked_arguments
def train_batched_together(
    batches: list[tuple[list[TrainConfig], list[str | os.PathLike]]],
    *,
    stop_at_perfect: bool = False,
    progress: bool = False,
    cuda_graph: bool = False,
) -> list[list[dict | str]]:
    """Several batches (each ``(configs, outs)`` as :func:`train_batched` takes them, of any
    shapes) trained together (:func:`train_groups`): on a GPU each batch on its own CUDA stream,
    so that their steps overlap (with ``cuda_graph`` on an H100, 8-15 batches of 10 runs gave
    2.5-3x one batch's throughput, docs/batched.md); on a CPU one after another each step, which
    gains nothing. Each batch's numbers are its own, as trained alone. Returns per batch what
    :func:`train_batched` returns."""
    batches = _as_batches(batches)
    if not batches:
        raise HamError("no batches to train; accepted: one (configs, outs) pair or more")
    for configs, outs in batches:
        _check_outs(configs, outs)
    every = [o for _, outs in batches for o in outs]
    if len({str(o.resolve()) for o in every}) != len(every):
        raise HamError("two runs of the batches share a directory; give each its own")
    made = [o for o in every if not o.exists()]
    opened: list[Run] = []
    tables: dict = {}  # each glance table loaded once for all batches
    try:
        with contextlib.ExitStack() as locks:
            for out in every:  # each run's folder held, as train and resume hold theirs: a
                out.mkdir(parents=True, exist_ok=True)  # `ham train --resume` of one of them
                locks.enter_context(folder_lock(out))  # at the same time is refused
            try:
                groups = [_open_group(c, o, stop_at_perfect, cuda_graph, opened, tables)
                          for c, o in batches]  # fmt: skip
                return train_groups(groups, progress)
            finally:
                for r in opened:
                    r.close()
    except BaseException:
        for f in made:  # a batch that did not start leaves no folder behind
            with contextlib.suppress(OSError):  # not empty: the run started
                f.rmdir()
        raise


def _as_batches(batches) -> list[tuple[list[TrainConfig], list[Path]]]:
    """``batches`` as lists of configs and paths, or a :class:`HamError` naming what is off."""
    pair = "a list of (configs, outs) pairs: a list of TrainConfig and a list of paths each"
    if not isinstance(batches, list | tuple):
        raise HamError(f"batches = {brief(batches)}; accepted: {pair}")
    out = []
    for k, batch in enumerate(batches):
        if not (isinstance(batch, list | tuple) and len(batch) == 2):
            raise HamError(f"batch {k} = {brief(batch)}; accepted: {pair}")
        configs, outs = batch
        if not (isinstance(configs, list | tuple)
                and all(isinstance(c, TrainConfig) for c in configs)):  # fmt: skip
            raise HamError(f"configs = {brief(configs)}; accepted: a list of TrainConfig")
        if not (isinstance(outs, list | tuple)
                and all(isinstance(o, str | os.PathLike) and str(o) for o in outs)):  # fmt: skip
            raise HamError(f"outs = {brief(outs)}; accepted: a list of paths (str or "
                           "os.PathLike), one per config")  # fmt: skip
        out.append((list(configs), [Path(o) for o in outs]))
    return out


def _open_group(
    configs: list[TrainConfig],
    outs: list[Path],
    stop_at_perfect: bool,
    cuda_graph: bool,
    opened: list[Run],
    tables: dict,
) -> BatchedRuns:
    """One batch's runs, fresh or resumed from their checkpoints, as a :class:`BatchedRuns`
    (its runs added to ``opened``, which the caller closes; its table from ``tables``)."""
    configs = list(configs)
    resumed = []
    for k, (c, out) in enumerate(zip(configs, outs, strict=True)):
        if (out / CHECKPOINT_FILE).exists():
            saved = read_run_config(out)
            # where it runs (device, table path) may change between invocations, as on resume
            saved = replace(saved, steps=c.steps, device=c.device, table=c.table)
            if not _same_run(saved, c):
                raise HamError(
                    f"{str(out)!r} holds another run (seed {saved.seed}); accepted: the same "
                    "config, or an empty directory"
                )
            configs[k] = saved
            resumed.append(k)
    runs = _open_runs(configs, outs, tables)
    opened.extend(runs)
    for k, c in enumerate(configs):  # a fresh run's start, as train() makes it
        if k not in resumed and c.init_from is not None:
            start_from(runs[k], c.init_from)
    for k in resumed:
        runs[k].load_state_dict(load_checkpoint(outs[k]))
        if runs[k].step > configs[k].steps:
            raise HamError(f"the run in {str(outs[k])!r} is at step {runs[k].step}, beyond "
                           f"steps {configs[k].steps}")  # fmt: skip
    stopped = {k: s for k, out in enumerate(outs) if (s := _stopped_at(out)) is not None}
    return BatchedRuns(runs, outs, stop_at_perfect, stopped, cuda_graph)


def _stopped_at(out: Path) -> int | None:
    """The step a run stopped at with a perfect evaluation (``None``: it did not)."""
    try:
        step = json.loads((out / METRICS_FILE).read_text()).get(STOPPED_KEY)
    except (OSError, ValueError, AttributeError):  # none, or damaged: taken as not stopped
        return None
    return step if isinstance(step, int) and not isinstance(step, bool) else None
