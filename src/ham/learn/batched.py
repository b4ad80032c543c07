"""Batched training: N runs of one shape trained as one stacked model (beyond the paper).

The paper's grid is hundreds of small runs (LSTM 256, batch 64); one run at a time pays every
operation's overhead for a few small matrices. Here N runs whose configs differ only in
:data:`PER_RUN` fields (``seed``, ``steps``, the learning-rate schedule, the momentum, the loss's
``beta`` and reductions, the normalization, the BPTT truncation, the evaluation and logging
settings: the seeds of a grid cell, or a sweep of rates) go through each step together: their weights are stacked along
a leading run axis, one glance of all N runs is one pass through the stacked layers
(:class:`_StackedHam`, mirroring :mod:`ham.model` line by line), the hybrid loss is
:func:`torch.vmap` of :func:`ham.learn.hybrid_loss.hybrid_loss`, and one backward yields every
run's gradient (the runs' graphs are disjoint). Each layer is one ``bmm`` for all runs (on an AMD
CPU each large product is one oneDNN call per run: :func:`_mm_nt`), the layers reading the core's
output are one layer (:meth:`_StackedHam._heads`), weight gradients are deferred to one product per
layer over all glances, so is the tactile network's whole backward (concat combiners:
:meth:`_StackedHam._tactile_backward`; on the CPU each of its ReLUs writes straight into the record
the next layer reads, and ``[g, h]`` is never joined: :meth:`_Layer.slot`), the LSTM cell is fused
(:class:`_TanhLSTMCell`, its backward compiled on the CPU), from 6 glances on the CPU the gates'
forward is two products of half the outputs (:meth:`_Layer.split_forward`), and on the CPU one
fused SGD call steps all runs (docs/agent.md#batched-runs has the measurements).

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
import warnings
from dataclasses import replace
from pathlib import Path

import torch
from torch.nn import functional as F

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.learn.evaluation import EvalResult, eval_result
from ham.learn.hybrid_loss import hybrid_loss
from ham.learn.train import (
    CHECKPOINT_FILE,
    CONFIG_FILE,
    METRICS_FILE,
    TIMING_FILE,
    Run,
    TrainConfig,
    _check_loss,
    _check_weights,
    _evaluate,
    _log_eval,
    _write_atomic,
    _write_json,
    load_checkpoint,
    read_json,
    stream_seed,
)
from ham.model.agent import Episode, HamConfig
from ham.model.location_net import truncated_normal, uniform_locations
from ham.model.policy import TruncatedGaussian, Uniform
from ham.world.devices import cpu_info
from ham.world.source import check_model_fits, make_source

STOPPED_KEY = "stopped_at_perfect"
_PARTS = ("classification", "reinforce", "baseline_loss")  # TensorBoard, as train_loop


# What may differ between the runs of one batched model: each run steps at its own learning
# rate (its schedule, its location network's scale) and momentum (Nesterov or not), has its own
# loss (beta, the reductions over the batch), normalizes its glances its own way, and is
# evaluated and logged on its own cadence, batches and policy; and of the model, whether its
# core's state is detached between glances (model.truncate_bptt). Everything else (the model,
# the world, the optimizer, the batch) is one for the group.
PER_RUN = ("seed", "steps", "lr", "lr_decay", "lr_step", "lr_min", "momentum", "nesterov",
           "policy_lr_scale", "beta", "classification_reduction", "reinforce_reduction",
           "normalization", "eval_every", "eval_batches", "eval_policy", "log_every")  # fmt: skip


def shape_key(config: TrainConfig) -> str:
    """Runs with equal keys can share one batched model: the config without the fields that
    may differ per run (:data:`PER_RUN`, and the model's ``truncate_bptt``; a beta of 0 skips
    the REINFORCE term, so it is its own shape)."""
    d = config.to_dict()
    for name in PER_RUN:
        d.pop(name)
    d["model"].pop("truncate_bptt")  # the core's state detached per run (_StackedHam.truncate)
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
    if config.model.policy not in ("learned", "random"):
        raise HamError(
            f"policy {config.model.policy!r} cannot be batched; accepted: learned, random "
            "(train it with ham train or --executor local)"
        )
    if config.model.stay_gate:
        raise HamError(
            "stay_gate cannot be batched; accepted: no --stay-gate (train it with ham train or "
            "--executor local)"
        )
    if config.model.first_glance != "random":
        raise HamError(
            f"first_glance {config.model.first_glance!r} cannot be batched; accepted: random "
            "(train it with ham train or --executor local)"
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
_FUSED_SGD = getattr(torch, "_fused_sgd_", None)


def _onednn_ok(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Whether ``a[k] @ b[k]^T`` goes to oneDNN one run at a time (see :func:`_mm_nt`)."""
    return (
        _PER_RUN_ONEDNN
        and _LINEAR_ONEDNN is not None
        and a.device.type == "cpu"
        and a.dtype == torch.float32
        and a.shape[1] >= 16
        and b.shape[1] * b.shape[2] >= _ONEDNN_MIN
    )


# oneDNN's fp32 linear; None where this torch lacks it (then every product is a bmm)
_LINEAR_ONEDNN = getattr(getattr(torch.ops, "mkldnn", None), "_linear_pointwise", None)
if _LINEAR_ONEDNN is not None and not torch.backends.mkldnn.is_available():
    _LINEAR_ONEDNN = None
# The CPU products' path, by what was measured (docs/agent.md#batched-runs): MKL, torch's BLAS,
# picks its kernels by the CPU's vendor. On AMD it runs AVX2 kernels, and one oneDNN product
# per run (AVX-512) is twice as fast as its batched bmm; on Intel it runs AVX-512 kernels, and
# its bmm makes the batched step 1.2-1.3x faster than oneDNN per run. Fixed per machine, so a
# run resumed on the same machine takes the same path (bit-identical resume).
_PER_RUN_ONEDNN = cpu_info("vendor_id") == "AuthenticAMD"
# tanh in the LSTM cell as 2 sigmoid(2x) - 1 (:class:`_TanhLSTMCell`): on AMD, where
# torch.tanh is slow; fixed per machine as the products' path
_SIGMOID_TANH = _PER_RUN_ONEDNN
# smaller layers (poses in, heads out, 256 -> 64): one bmm beats N small calls (measured)
_ONEDNN_MIN = 128 * 256
# The forward of a layer with this many outputs (the LSTM's gates: 1024), in a step of at least
# _SPLIT_GLANCES glances, as two products of half the outputs on a transposed copy of the
# weights made once per step (:meth:`_Layer.split_forward`). On an Intel Xeon (1.25 MiB of L2
# per core) MKL's product of 1024 outputs (a 2 MB panel of weights) takes 7.2 ms for 10 runs,
# two of 512 on contiguous halves 5.5 ms (at the paper's batch of 64 their outputs were the
# same to the bit; in general the same to float rounding); the transpose costs 7.8 ms a step,
# so it pays from 6 glances (docs/agent.md#batched-runs, the step's time against one product:
# 0.97x at 10 and 8 glances, 0.98x at 6, 1.00x at 4, 1.05x at 3).
_SPLIT_OUTPUTS = 1024
_SPLIT_GLANCES = 6


def _mm_nt(a: torch.Tensor, b: torch.Tensor, bias: torch.Tensor | None = None) -> torch.Tensor:
    """``a[k] @ b[k]^T (+ bias[k])`` for every run ``k``: ``a (N, M, K)``, ``b (N, P, K)``,
    either possibly a transposed view (never copied: a transposing copy costs more than the
    product).

    On an AMD CPU in fp32 (:data:`_PER_RUN_ONEDNN`), one oneDNN product per run: MKL's sgemm
    runs its AVX2 kernels there, oneDNN's AVX-512 kernels are twice as fast, and MKL's batched
    ``bmm`` is no faster than a loop of single products. Elsewhere (Intel: MKL's AVX-512
    kernels; CUDA: one launch for all runs) one ``bmm``, the bias added in place on the CPU
    (``baddbmm`` first copies the broadcast bias into the output: 10.2 vs 8.7 ms for the LSTM's
    gates of 10 runs) and by ``baddbmm`` on a GPU (docs/agent.md#batched-runs)."""
    if _onednn_ok(a, b):
        return torch.stack(
            [
                _LINEAR_ONEDNN(a[k], b[k], None if bias is None else bias[k], "none", [], "")
                for k in range(a.shape[0])
            ]
        )
    bt = b.transpose(1, 2)
    if bias is None:
        return torch.bmm(a, bt)
    if a.device.type == "cpu":
        return torch.bmm(a, bt).add_(bias.unsqueeze(1))
    return torch.baddbmm(bias.unsqueeze(1), a, bt)


def _columns(weight: torch.Tensor, width: int) -> torch.Tensor:
    """The first ``width`` input columns of ``weight (N, out, in)``, contiguous: oneDNN runs a
    weight with a row stride beyond its width ~600x slower (0.36 s for 64 x 256 by 256 x 1024)."""
    return weight if width == weight.shape[2] else weight[..., :width].contiguous()


def _joined(parts: list[tuple[torch.Tensor, torch.Tensor | None]]):
    """Stacked layers' weights and biases joined along their outputs (no gradient: the layers'
    gradients are deferred, :meth:`_Layer.grads`)."""
    with torch.no_grad():
        weight = torch.cat([w.detach() for w, _ in parts], 1)
        biases = [b for _, b in parts]
        bias = None if biases[0] is None else torch.cat([b.detach() for b in biases], 1)
    return weight, bias


def _relu_backward(grad: torch.Tensor, out: torch.Tensor, into: torch.Tensor) -> None:
    """``grad`` where the ReLU's output ``out`` is positive, else 0, written ``into`` (autograd's
    ReLU backward: ``threshold_backward`` of the output)."""
    torch.ops.aten.threshold_backward.grad_input(grad, out, 0.0, grad_input=into)


def _shifted(bias: torch.Tensor | None, shift: torch.Tensor, runs: int) -> torch.Tensor:
    """``bias (N, out)`` plus the constant ``shift (out,)`` (the shift alone without a bias)."""
    with torch.no_grad():
        return shift.expand(runs, -1) if bias is None else bias.detach() + shift


class _Layer:
    """One dense layer of N runs: ``y = x W^T + b``, ``x (N, B, in)``, ``W (N, out, in)``; an
    input narrower than ``in`` stands for itself padded with zeros (the LSTM's first glance:
    ``[g, h = 0]``), and only its columns of ``W`` take part (copied once per step).

    Its weight gradient is deferred: each application (one per glance) copies its input (or
    finds it written there: :meth:`slot`), and its output gradient in the backward pass, into
    the layer's record buffers, and
    :meth:`grads` turns one step's records into one product per run (``W``'s gradient over
    every glance at once, ``G * B`` rows deep) instead of one product and one accumulation per
    glance. The buffers live as long as the layer (the group's stacked weights): fresh
    buffers every step cost more in page faults than the copies."""

    def __init__(
        self,
        weight: torch.Tensor,
        bias: torch.Tensor | None,
        capacity: int,
        parts: list[tuple[torch.Tensor, torch.Tensor | None]] | None = None,
        grad_rows: int | None = None,
        shift: torch.Tensor | None = None,
    ) -> None:
        self.weight, self.bias = weight, bias
        # a constant the forward adds to every output row (the LSTM's forget bias): folded
        # into the bias once per step instead of one pass over the outputs per glance
        self.shift, self._forward_bias = shift, None
        # several layers reading one input, fused (the heads): their stacked weights, joined
        # along the outputs anew each step; only the first grad_rows outputs pass a gradient
        # to the input (the others read it detached)
        self.parts, self.grad_rows = parts, grad_rows
        if parts is not None:
            self.weight, self.bias = _joined(parts)
        self.capacity = capacity  # applications per step (the glances)
        self.xbuf: torch.Tensor | None = None  # (N, capacity * B, in)
        self.gbuf: torch.Tensor | None = None  # (N, capacity * B, out)
        self.rows = 0
        self.applied = 0
        self.filled: set[int] = set()
        self.narrow: dict[int, torch.Tensor] = {}  # width -> the weight's columns, this step
        self._halves: torch.Tensor | None = None  # this step's W^T halves (:meth:`halves`)

    def begin(self) -> None:
        self.applied = 0
        self.filled = set()
        self.narrow = {}
        self._halves = None
        self._forward_bias = None
        if self.parts is not None:  # this step's weights (the stacks are stepped in place)
            self.weight, self.bias = _joined(self.parts)

    def forward_bias(self) -> torch.Tensor | None:
        """The bias the forward adds: ``b`` plus the layer's shift, once per step."""
        if self.shift is None:
            return self.bias
        if self._forward_bias is None:
            self._forward_bias = _shifted(self.bias, self.shift, self.weight.shape[0])
        return self._forward_bias

    def halves(self) -> torch.Tensor:
        """``W^T`` in two contiguous halves of the outputs (:func:`_halves`), once per step."""
        if self._halves is None:
            with torch.no_grad():
                w = self.weight.detach()
                self._halves = _compiled("halves", _halves, _halves_eager,
                                         "the batched gates' transpose", w)  # fmt: skip
        return self._halves

    def split_forward(self, x: torch.Tensor) -> bool:
        """Whether the forward runs as two products of half the outputs on :meth:`halves`
        (:data:`_SPLIT_OUTPUTS`): an fp32 CPU ``bmm`` of a layer this wide (the LSTM's gates),
        applied often enough in a step to pay for the transpose. A narrower input (the first
        glance's ``g``) reads the halves' first rows, and its input gradient the weight's
        columns in place (a strided ``bmm``): no copy of the columns."""
        w = self.weight
        return (
            x.device.type == "cpu"
            and x.dtype == torch.float32
            and w.shape[1] >= _SPLIT_OUTPUTS
            and w.shape[1] % 2 == 0
            and self.capacity >= _SPLIT_GLANCES
            and not _onednn_ok(x, w)
        )

    def columns(self, width: int) -> torch.Tensor:
        """The weight's first ``width`` columns (:func:`_columns`), once per step."""
        if width not in self.narrow:
            with torch.no_grad():
                self.narrow[width] = _columns(self.weight.detach(), width)
        return self.narrow[width]

    def slot(self, like: torch.Tensor) -> torch.Tensor:
        """The record of the next application, ``(N, B, in)`` (``like``: its input's rows,
        device and dtype): an input written straight into it (:meth:`_StackedHam.glance`'s
        ReLUs) is not copied again by :meth:`__call__`."""
        slot, rows = self.applied, like.shape[1]
        if self.xbuf is None or slot >= self.capacity or rows != self.rows:
            if self.xbuf is not None:  # more applications than glances: a layout this
                raise HamError(f"batched layer applied {slot + 1} times in a step")  # misses
            self.rows = rows
            n, out, width = self.weight.shape
            self.xbuf = like.new_empty(n, self.capacity * rows, width)
            self.gbuf = like.new_empty(n, self.capacity * rows, out)
        return self.xbuf[:, slot * rows : (slot + 1) * rows]

    def __call__(self, *blocks: torch.Tensor) -> torch.Tensor:
        """The layer applied to its input, given as column blocks (``[g, h]``: the LSTM's
        gates), each copied into the record unless it was written there (:meth:`slot`);
        without a block for the last columns they count as zeros."""
        self.slot(blocks[0])
        self.applied += 1
        return _LayerFn.apply(self, self.applied - 1, self.weight, self.forward_bias(), *blocks)

    def fill(self, slot: int, blocks: tuple[torch.Tensor, ...]) -> torch.Tensor:
        """The blocks copied into record ``slot`` (those not written there already); the
        input to multiply: one contiguous block as it is, else the record's columns."""
        r = self.rows
        record = self.xbuf[:, slot * r : (slot + 1) * r]
        width = 0
        for b in blocks:
            into = record[..., width : width + b.shape[2]]
            if not _is_view(b, into):
                into.copy_(b)
            width += b.shape[2]
        if width < record.shape[2]:
            record[..., width:].zero_()
        if len(blocks) == 1 and blocks[0].is_contiguous():
            return blocks[0]
        return record[..., :width]

    def grads(self) -> tuple[torch.Tensor, torch.Tensor | None] | None:
        """The weight and bias gradients of the step (``None``: the layer took no part)."""
        if not self.filled:
            return None
        r = self.rows
        for slot in set(range(self.applied)) - self.filled:  # an output the loss never read
            self.gbuf[:, slot * r : (slot + 1) * r].zero_()
        x, g = self.xbuf[:, : self.applied * r], self.gbuf[:, : self.applied * r]
        gw = _mm_nt(g.transpose(1, 2), x.transpose(1, 2))
        return gw, None if self.bias is None else g.sum(1)


class _LayerFn(torch.autograd.Function):
    """The autograd node of one :class:`_Layer` application: the input gradient now (split
    along the input's column blocks), the weight gradient recorded for :meth:`_Layer.grads`
    (so ``W`` and ``b`` get none here)."""

    @staticmethod
    def forward(ctx, layer, slot, weight, bias, *blocks):
        # the record filled here, not before: a block may be a view of the record made by
        # another custom Function (g), which autograd forbids using after its base changed
        x = layer.fill(slot, blocks)
        ctx.layer, ctx.slot, ctx.width = layer, slot, x.shape[2]
        ctx.widths = [b.shape[2] for b in blocks]
        ctx.split = layer.split_forward(x)
        if ctx.split:
            t = layer.halves()[:, :, : ctx.width]
            h = t.shape[3]
            y = x.new_empty(x.shape[0], x.shape[1], 2 * h)
            torch.bmm(x, t[0], out=y[..., :h])
            torch.bmm(x, t[1], out=y[..., h:])
            return y if bias is None else y.add_(bias.unsqueeze(1))
        return _mm_nt(x, layer.columns(ctx.width), bias)

    @staticmethod
    def backward(ctx, grad):
        layer, slot, r = ctx.layer, ctx.slot, ctx.layer.rows
        layer.gbuf[:, slot * r : (slot + 1) * r].copy_(grad)
        layer.filled.add(slot)
        w = layer.weight.detach()[..., : ctx.width] if ctx.split else layer.columns(ctx.width)
        gx = None
        if any(ctx.needs_input_grad[4:]):
            k = layer.grad_rows
            if k is not None:  # the outputs that read the input detached pass no gradient
                grad, w = grad[..., :k], w[:, :k]
            gx = _mm_nt(grad, w.transpose(1, 2))
        blocks = [None] * len(ctx.widths) if gx is None else gx.split(ctx.widths, -1)
        return None, None, None, None, *blocks


def _grouped(items, key) -> dict:
    """``items`` by ``key(item)``, in order: ``{key: [item, ...]}``."""
    out: dict = {}
    for item in items:
        out.setdefault(key(item), []).append(item)
    return out


def _pressure(runs: list[Run], flat_objects: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """The glances ``(N, B, N^2)`` of ``runs`` at poses ``q (N, B, 2)`` on objects
    ``flat_objects (N * B,)``, as each run's :meth:`HapticEnv.glance` gives them: one lookup
    for all runs of one normalization (their envs share the glance source)."""
    n, rows = q.shape[0], q.shape[1]
    kinds = _grouped(range(n), lambda k: runs[k].env.normalization)
    if len(kinds) == 1:
        return runs[0].env.glance(flat_objects, q.reshape(-1, 2)).view(n, rows, -1)
    objects, out = flat_objects.view(n, rows), None
    for ks in kinds.values():
        idx = torch.tensor(ks, device=q.device)
        part = runs[ks[0]].env.glance(objects.index_select(0, idx).reshape(-1),
                                      q.index_select(0, idx).reshape(-1, 2))  # fmt: skip
        part = part.view(len(ks), rows, -1)
        out = part.new_empty(n, rows, part.shape[2]) if out is None else out
        out.index_copy_(0, idx, part)
    return out


def _is_view(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Whether ``a`` is the very same elements as ``b`` (a view of it, as written; the stride
    of an axis of size 1 does not matter)."""
    return (
        a.data_ptr() == b.data_ptr()
        and a.shape == b.shape
        and all(n == 1 or x == y for n, x, y in zip(a.shape, a.stride(), b.stride(), strict=True))
        and a.device == b.device
    )


def _cell_backward(dh, dc1, act, tc, cell):
    """The gradient of the LSTM cell (:class:`_TanhLSTMCell`) with respect to its gates and
    its input cell state: ``act`` holds the activated gates ``(sigmoid i, sigmoid(f + b_f),
    tanh u, sigmoid o)`` along its axis -2, ``tc = tanh(c')``. One expression, so that
    :func:`torch.compile` makes it one loop over the step's tensors."""
    si, sf, tu, so = act.unbind(-2)
    dcell = dh * so * (1 - tc * tc) + dc1
    di = dcell * tu * si * (1 - si)
    df = dcell * cell * sf * (1 - sf)
    du = dcell * si * (1 - tu * tu)
    do = dh * tc * so * (1 - so)
    return torch.stack([di, df, du, do], -2).flatten(-2), dcell * sf


# The compiled backward: on the CPU, when the step's cell state has at least this many entries
# (the paper's 10 runs x 64 x 256: 163,840; a test's tiny models stay eager). Eager, the
# backward is a dozen passes over tensors that outgrow the caches (3.2 ms per glance of 10
# runs at the paper's size on an Intel Xeon), compiled one (0.7 ms): docs/agent.md#batched-runs.
# Compiled once for any shape (dynamic): a group that loses runs keeps its kernel (one compile
# per shape would reach dynamo's limit of 8 and fall back to eager mid-run); elementwise, its
# numbers equal the eager expression's (measured: equal to the bit at 10 x 64 x 256).
_COMPILE_MIN = 1 << 16
# "backward" (the cell's), "halves" (:func:`_halves`): the compiled function, or why it failed
_COMPILED: dict[str, object] = {}


def _compiled(key: str, fn, eager, what: str, *args):
    """``fn(*args)`` compiled once for any shape (``_COMPILED[key]``); where compiling fails
    (no C++ compiler) it warns once, naming ``what``, and runs ``eager`` (the same numbers)
    from then on."""
    compiled = _COMPILED.get(key)
    if compiled is None:
        compiled = _COMPILED[key] = torch.compile(fn, dynamic=True)
    if isinstance(compiled, str):
        return eager(*args)
    try:
        return compiled(*args)
    except Exception as exc:  # noqa: BLE001 - any compiler failure: the same numbers, eager
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        _COMPILED[key] = reason
        warnings.warn(f"{what} runs eager (torch.compile failed: {reason})", stacklevel=3)
        return eager(*args)


def _backward(dh, dc1, act, tc, cell):
    """:func:`_cell_backward`, compiled where that pays (:data:`_COMPILE_MIN`, CPU) and works;
    where compiling fails (no C++ compiler) it warns once and stays eager."""
    if dc1 is None:
        dc1 = torch.zeros_like(dh)
    if dh.device.type != "cpu" or dh.numel() < _COMPILE_MIN:
        return _cell_backward(dh, dc1, act, tc, cell)
    return _compiled("backward", _cell_backward, _cell_backward, "the batched LSTM cell",
                     dh, dc1, act, tc, cell)  # fmt: skip


def _halves(w: torch.Tensor) -> torch.Tensor:
    """``W^T`` of ``w (N, out, in)`` in two contiguous halves of the outputs: ``(2, N, in,
    out / 2)``. Compiled, a tiled transpose (7.8 ms for the paper's gates of 10 runs on an Intel
    Xeon, against 13.7 for torch's own 2-D transposing copies: :func:`_halves_eager`)."""
    n, out, width = w.shape
    return w.view(n, 2, out // 2, width).permute(1, 0, 3, 2).contiguous()


def _halves_eager(w: torch.Tensor) -> torch.Tensor:
    """:func:`_halves` as one 2-D transposing copy per run and half (torch's blocked transpose:
    twice as fast as the 3-D permuted copy); the same numbers."""
    n, out, width = w.shape
    h = out // 2
    t = w.new_empty(2, n, width, h)
    for r in range(n):
        t[0, r].copy_(w[r, :h].t())
        t[1, r].copy_(w[r, h:].t())
    return t


class _TanhLSTMCell(torch.autograd.Function):
    """:class:`ham.model.core.LSTMCore`'s cell after its gate product, fused:
    ``c' = sigmoid(f) c + sigmoid(i) tanh(u)``, ``h = sigmoid(o) tanh(c')``, gates
    ``(i, f, u, o)`` along the last axis (the forget bias ``b_f`` already in ``f``: the gate
    layer's bias holds it, :meth:`_StackedHam.glance`), with a hand-written backward
    (:func:`_backward`, compiled at the paper's size on the CPU) instead of autograd's dozen
    elementwise nodes.

    ``tanh`` is ``torch.tanh`` where it is fast, and ``2 sigmoid(2x) - 1`` on an AMD CPU, where
    ``torch.tanh`` took ten times as long as ``torch.sigmoid`` (0.36 vs 0.04 ms on 10 x 64 x
    256; on an Intel Xeon 0.05 vs 0.09 ms). Equal to the module's cell to float rounding
    (tested against single runs)."""

    _constants: dict = {}

    @classmethod
    def _scale(cls, z: torch.Tensor) -> torch.Tensor:
        """``(1, 1, 2, 1)`` per gate, spelled out along the units: an operand broadcast along
        the last axis takes PyTorch's unvectorized loop (an ``addcmul`` over 10 x 64 x 1024
        gates: 0.32 ms, against 0.06 ms with it spelled out)."""
        key = (z.shape[-1], z.device, z.dtype)
        if key not in cls._constants:
            scale = z.new_tensor([1.0, 1.0, 2.0, 1.0]).unsqueeze(-1)
            cls._constants[key] = scale.expand(4, z.shape[-1]).contiguous()
        return cls._constants[key]

    @staticmethod
    def forward(ctx, gates, cell):
        shape = gates.shape
        z = gates.view(*shape[:-1], 4, shape[-1] // 4)
        if _SIGMOID_TANH:  # one sigmoid of (i, f, 2u, o): tanh(u) = 2 sigmoid(2u) - 1
            act = torch.mul(z, _TanhLSTMCell._scale(z)).sigmoid_()
            act[..., 2, :].mul_(2).sub_(1)
        else:
            act = torch.sigmoid(z)
            torch.tanh(z[..., 2, :], out=act[..., 2, :])
        si, sf, tu, so = act.unbind(-2)
        c1 = torch.addcmul(sf * cell, si, tu)
        tc = torch.sigmoid(c1 * 2).mul_(2).sub_(1) if _SIGMOID_TANH else torch.tanh(c1)
        ctx.save_for_backward(act, tc, cell)
        return so * tc, c1

    @staticmethod
    def backward(ctx, dh, dc1):
        act, tc, cell = ctx.saved_tensors
        dgates, dcell = _backward(dh, dc1, act, tc, cell)
        return dgates, (dcell if ctx.needs_input_grad[1] else None)


class _TactileOutput(torch.autograd.Function):
    """``g``, the tactile network's output, computed without autograd, entering the graph:
    its gradient is recorded (:meth:`_StackedHam._record_dg`) and the tactile network's
    backward runs once for all glances after the backward pass
    (:meth:`_StackedHam._tactile_backward`). ``anchor`` (a stacked weight) only gives the node
    an input that requires a gradient."""

    @staticmethod
    def forward(ctx, g, anchor, net, slot):
        ctx.net, ctx.slot = net, slot
        return g.view_as(g)

    @staticmethod
    def backward(ctx, dg):
        ctx.net._record_dg(ctx.slot, dg)
        return None, None, None, None


class _StackedHam:
    """The HAM's layers (:mod:`ham.model`) over weights stacked along a leading run axis: one
    glance of N runs, ``(N, B, ...)`` in and out. Each line mirrors its module (tactile network,
    core, classifier, baseline, location network), detaches included."""

    def __init__(self, config: HamConfig) -> None:
        self.c = config
        self.used: set[str] = set()  # the weights read: checked against the model's once
        self.layers: dict[str, _Layer] = {}
        self._heads_names = ["classifier.dense", "baseline.dense"]
        # the tactile network's backward deferred to one pass over all glances (the concat
        # combiners: its inputs, pressure and pose, take no gradient, and each layer's input
        # record holds the ReLU output its backward needs)
        self._defer = config.combiner in ("concat1", "concat2")
        self._dg: torch.Tensor | None = None  # (N, glances * B, combine units): d loss / d g
        self._dg_slots = 0
        self._dg_filled: set[int] = set()
        self._shift: torch.Tensor | None = None  # the forget bias along the gates
        # which runs detach the core's state between glances (truncated BPTT): a bool per run
        # (N, 1, 1) where the runs differ, else None and the config's one choice
        self.truncate: torch.Tensor | None = None
        if config.policy == "learned" and config.glances > 1:  # a policy that chooses glances
            self._heads_names += ["location.mu", "location.sigma"]

    def begin(self, p: dict) -> None:
        """A new step of the weights ``p``: the layers' records start over (new layers when
        the stack changed: a run left the group)."""
        if p is not getattr(self, "_p", None):
            self._p, self.layers, self._dg = p, {}, None
        for layer in self.layers.values():
            layer.begin()
        self._dg_slots = 0
        self._dg_filled = set()

    def grads(self) -> dict[str, torch.Tensor]:
        """The step's weight gradients by parameter name, after the backward pass."""
        self._tactile_backward()
        out = {}
        for name, layer in self.layers.items():
            g = layer.grads()
            if g is None:
                continue
            if layer.parts is None:
                parts = [(name, g[0], g[1])]
            else:  # the fused heads: each layer's rows of the joined gradient
                sizes = [w.shape[1] for w, _ in layer.parts]
                gb = [None] * len(sizes) if g[1] is None else g[1].split(sizes, 1)
                parts = zip(self._heads_names, g[0].split(sizes, 1), gb, strict=True)
            for n, gw, gb in parts:
                out[n + ".weight"] = gw.contiguous()
                if gb is not None:
                    out[n + ".bias"] = gb.contiguous()
        return out

    def _record_dg(self, slot: int, dg: torch.Tensor) -> None:
        n, r, width = dg.shape
        # exactly one slot per glance: _tactile_backward reads the rows off this shape
        if self._dg is None or self._dg.shape != (n, self.c.glances * r, width):
            self._dg = dg.new_empty(n, self.c.glances * r, width)
        self._dg[:, slot * r : (slot + 1) * r].copy_(dg)
        self._dg_filled.add(slot)

    @torch.no_grad()
    def _tactile_backward(self) -> None:
        """The tactile network's backward (ReLU, ``combine`` layers, ``what`` and ``where``)
        for every glance at once, from the gradients :class:`_TactileOutput` recorded: each
        layer's output gradient into its record (:meth:`_Layer.grads` makes the weight
        gradients), the input gradients as one product per run ``G * B`` rows deep."""
        if not self._dg_filled:
            return
        c, n = self.c, self._dg_slots
        rows = self._dg.shape[1] // c.glances
        r = n * rows
        for slot in set(range(n)) - self._dg_filled:  # a glance whose g the loss never read
            self._dg[:, slot * rows : (slot + 1) * rows].zero_()
        grad = self._dg[:, :r]
        core = self.layers["core.gates" if c.core == "lstm" else "core.dense"]
        post = core.xbuf[:, :r, : grad.shape[2]]  # g, the last ReLU's output
        combine = ["tactile.combine.2"] if c.combiner == "concat2" else []
        for name in [*combine, "tactile.combine.0"]:
            layer = self.layers[name]
            _relu_backward(grad, post, layer.gbuf[:, :r])
            layer.filled = set(range(n))
            grad = _mm_nt(layer.gbuf[:, :r], layer.weight.transpose(1, 2))
            post = layer.xbuf[:, :r]
        split = c.what_units  # grad, post: d loss / d [what, where] and [what, where]
        for name, cols in (
            ("tactile.what", slice(0, split)),
            ("tactile.where", slice(split, None)),
        ):
            layer = self.layers[name]
            _relu_backward(grad[..., cols], post[..., cols], layer.gbuf[:, :r])
            layer.filled = set(range(n))

    def _heads(self, p: dict, tau: torch.Tensor, record: bool) -> list[torch.Tensor]:
        """The layers reading the core's output ``tau`` as one layer (one product, one record
        of ``tau``): the classifier (its gradient reaches ``tau``), the baseline and the
        location network's mu and sigma (they read ``tau`` detached). Their outputs, in that
        order (the location's only when the policy is learned and there are glances to
        choose)."""
        names = self._heads_names
        if not record:
            w, b = _joined([(p[n + ".weight"], p.get(n + ".bias")) for n in names])
            out = _mm_nt(tau, w, b)
        else:
            layer = self.layers.get("heads")
            if layer is None:
                parts = [(p[n + ".weight"], p.get(n + ".bias")) for n in names]
                for n in names:
                    self.used.update({n + ".weight", n + ".bias"} & p.keys())
                layer = self.layers["heads"] = _Layer(
                    None, None, self.c.glances, parts=parts, grad_rows=parts[0][0].shape[1]
                )
            out = layer(tau)
        return out.split([p[n + ".weight"].shape[1] for n in names], -1)

    def _lin(
        self,
        p: dict,
        name: str,
        x: torch.Tensor,
        record: bool = True,
        shift: torch.Tensor | None = None,
    ) -> torch.Tensor:
        weight, bias = p[name + ".weight"], p.get(name + ".bias")
        if not record:  # evaluation: no gradient to defer
            if shift is not None:
                bias = _shifted(bias, shift, weight.shape[0])
            return _mm_nt(x, _columns(weight, x.shape[-1]), bias)
        return self._layer(p, name)(x)

    def _layer(self, p: dict, name: str) -> _Layer:
        """The recording layer ``name`` (made on its first use in a stack; the LSTM's gates
        add the forget bias, :meth:`_forget_shift`)."""
        layer = self.layers.get(name)
        if layer is None:
            self.used.update({name + ".weight", name + ".bias"} & p.keys())
            weight, bias = p[name + ".weight"], p.get(name + ".bias")
            shift = self._forget_shift(p) if name == "core.gates" else None
            layer = self.layers[name] = _Layer(weight, bias, self.c.glances, shift=shift)
        return layer

    def _relu_into(self, p: dict, y: torch.Tensor, name: str, at: int = 0) -> torch.Tensor:
        """``relu(y)``, written straight into the record of layer ``name``'s next application
        at column ``at``, where that layer reads it (:meth:`_Layer.slot`: no copy there). Only
        on the CPU's ``bmm`` path: oneDNN and CUDA get a plain ReLU, which the layer copies
        (oneDNN is slow on a strided input, CUDA untested so)."""
        if y.device.type != "cpu" or _PER_RUN_ONEDNN:
            return torch.relu(y)
        slot = self._layer(p, name).slot(y)
        return torch.clamp_min(y, 0.0, out=slot[..., at : at + y.shape[2]])

    def _forget_shift(self, p: dict) -> torch.Tensor:
        """``(0, b_f, 0, 0)`` along the LSTM's gates: the forget bias, added with the gates'
        bias (the single model adds it to ``f`` in the cell; equal to float rounding)."""
        if self._shift is None:
            w, h = p["core.gates.weight"], self.c.hidden_units
            self._shift = w.new_zeros(4 * h)
            self._shift[h : 2 * h] = self.c.forget_bias
        return self._shift

    def glance(self, p: dict, pressure, q, state, with_policy: bool, record: bool = True):
        """One glance: ``record=False`` for an evaluation (no gradient; the layers' records of
        the training step are left alone)."""
        c = self.c

        def lin(p, name, x, shift=None):
            return self._lin(p, name, x, record, shift)

        # HapticAttentionModel.step: the pose fed to the tactile network
        location = torch.stack([q[..., 0], q[..., 1] * c.phi_scale], dim=-1)
        # TactileNetwork (deferred: no graph here, its backward after the backward pass;
        # each ReLU's output written where the next layer records its input)
        defer = record and self._defer
        with torch.no_grad() if defer else contextlib.nullcontext():
            if defer:  # the concat combiners: each layer's input written into its record
                chain = ["tactile.combine.0", "tactile.combine.2"][: int(c.combiner[-1])]
                chain.append("core.gates" if c.core == "lstm" else "core.dense")
                what = self._relu_into(p, lin(p, "tactile.what", pressure), chain[0])
                where = self._relu_into(p, lin(p, "tactile.where", location), chain[0],
                                        what.shape[2])  # fmt: skip
                g = self._layer(p, chain[0])(what, where)
                for k in range(1, len(chain)):
                    g = self._relu_into(p, g, chain[k])
                    if k + 1 < len(chain):
                        g = self._layer(p, chain[k])(g)
            else:
                what = torch.relu(lin(p, "tactile.what", pressure))
                where = torch.relu(lin(p, "tactile.where", location))
                if c.combiner == "add":
                    g = what + where
                elif c.combiner == "mul":
                    g = what * where
                else:
                    g = torch.cat([what, where], dim=-1)
                    for k in range(2 if c.combiner == "concat2" else 1):
                        g = torch.relu(lin(p, f"tactile.combine.{2 * k}", g))
        if defer:
            g = _TactileOutput.apply(g, p["tactile.what.weight"], self, self._dg_slots)
            self._dg_slots += 1
        # the core: LSTMCore or MLPCore
        if c.core == "lstm":
            shift = self._forget_shift(p)  # f + b_f from the gates' layer
            if state is None:  # LSTMCore.initial_state: h = c = 0
                # the gates of [g, 0]: the layer takes g alone (half the product)
                cell = g.new_zeros(*g.shape[:-1], c.hidden_units)
                gates = lin(p, "core.gates", g, shift)
            else:
                h, cell = state
                if record and self.truncate is not None:  # some runs truncated: no gradient
                    # through their state (an evaluation takes no gradient at all)
                    h = torch.where(self.truncate, h.detach(), h)
                    cell = torch.where(self.truncate, cell.detach(), cell)
                elif c.truncate_bptt:
                    h, cell = h.detach(), cell.detach()
                if record:  # [g, h] as blocks: written into the layer's record, not joined
                    gates = self._layer(p, "core.gates")(g, h)
                else:
                    gates = lin(p, "core.gates", torch.cat([g, h], dim=-1), shift)
            if c.lstm_activation == "tanh":
                tau, cell = _TanhLSTMCell.apply(gates, cell)
            else:
                i, f, u, o = gates.chunk(4, dim=-1)
                cell = torch.sigmoid(f) * cell + torch.sigmoid(i) * torch.relu(u)
                tau = torch.sigmoid(o) * torch.relu(cell)
            state = (tau, cell)
        else:
            tau = torch.relu(lin(p, "core.dense", g))
        # Classifier, Baseline and LocationNetwork (these two read tau detached): one layer
        logits, baseline, *location = self._heads(p, tau, record)
        baseline = baseline.squeeze(-1)
        dist = None
        if with_policy and c.policy == "learned":
            mu = torch.tanh(location[0])
            s = location[1]
            sigma = F.softplus(s) if c.std_activation == "softplus" else torch.sigmoid(s)
            dist = (mu, sigma + c.sigma_min)
        return state, logits, baseline, dist


class BatchedRuns:
    """N :class:`Run` s of one shape, their weights stacked; :meth:`train` trains them all."""

    def __init__(
        self,
        runs: list[Run],
        outs: list[Path],
        stop_at_perfect: bool = False,
        stopped: dict[int, int] | None = None,
    ) -> None:
        self.runs, self.outs = list(runs), [Path(o) for o in outs]
        self.stop_at_perfect = stop_at_perfect
        self.results: dict[int, dict | str] = {}  # run index -> metrics, or the error line
        self.stopped: dict[int, int] = dict(stopped or {})  # run index -> the step it stopped
        self.active = [
            i for i in range(len(self.runs)) if not self._done(i) and i not in self.stopped
        ]
        _keep_freed_memory()
        self._template = self.runs[0].agent  # its config and initial state only
        self._net = _StackedHam(self._template.config)
        self._names = [n for n, _ in self.runs[0].agent.named_parameters()]
        self._params = [dict(r.agent.named_parameters()) for r in self.runs]
        # SGD (the paper's) is stepped for all runs at once; Adam by each run's own optimizer
        self._sgd = self.runs[0].config.optimizer == "sgd"
        self._lr_scale = [_lr_scales(r, p) for r, p in zip(self.runs, self._params, strict=True)]
        self._checked = False
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
        truncate = [self.runs[i].config.model.truncate_bptt for i in self.active]
        if all(t == self._template.config.truncate_bptt for t in truncate):
            self._net.truncate = None  # the stacked model's config says it for all
        else:  # the active runs' choices, as the stack's run axis
            device = next(iter(self.stacked.values())).device
            self._net.truncate = torch.tensor(truncate, device=device).view(-1, 1, 1)

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
        self.active = [i for i in self.active if i not in gone]
        for i in gone:  # its own compact copy of the weights and buffers, apart from the stack
            for p in self.runs[i].agent.parameters():
                p.data = p.data.clone()
            for st in self.runs[i].optimizer.state.values():
                if "momentum_buffer" in st:
                    st["momentum_buffer"] = st["momentum_buffer"].clone()
        if self.active:
            self._stack()

    def _sgd_step(self, runs: list[Run], stepping: list[int], grads: dict) -> None:
        """``torch.optim.SGD``'s update (momentum, Nesterov or not, no dampening or weight decay)
        of every stepping run over the stacked tensors: one fused pass per learning rate and
        momentum (PyTorch's ``_fused_sgd_``: the foreach optimizer's numbers to the last bit of
        the momentum buffer) instead of N optimizers looping over their parameters. Runs of one
        rate and momentum (the usual case: one schedule, one step) are updated as whole stacked
        tensors; others, and a group some of whose runs diverged, run by run."""
        by_setting: dict[tuple, list[int]] = {}
        for k in stepping:  # each run at its own schedule's rate, scales and momentum
            c, i = runs[k].config, self.active[k]
            key = (c.learning_rate(runs[k].step), c.momentum, c.nesterov,
                   tuple(self._lr_scale[i][n] for n in grads))  # fmt: skip
            by_setting.setdefault(key, []).append(k)
        if len(by_setting) == 1 and len(stepping) == len(runs):
            parts = [(slice(None), stepping[0])]
        else:
            parts = [(k, k) for ks in by_setting.values() for k in ks]
        if any(runs[k].config.momentum != 0 for k in stepping):
            for name in grads:
                if name not in self.buffers:
                    self._new_buffer(name, [None] * len(runs))
        with torch.no_grad():
            for idx, k in parts:
                c, scales = runs[k].config, self._lr_scale[self.active[k]]
                lr, m = c.learning_rate(runs[k].step), c.momentum
                by_scale: dict[float, list[str]] = {}
                for name in grads:
                    by_scale.setdefault(scales[name], []).append(name)
                for scale, names in by_scale.items():
                    ps = [self.stacked[n][idx] for n in names]
                    gs = [grads[n][idx] for n in names]
                    if m == 0:  # the optimizer keeps no buffers
                        torch._foreach_add_(ps, gs, alpha=-(lr * scale))
                    elif _FUSED_SGD is not None:
                        # zero-initialized buffers: 0 * m + g is exactly the first buffer
                        _FUSED_SGD(ps, gs, [self.buffers[n][idx] for n in names],
                                   weight_decay=0.0, momentum=m, lr=lr * scale, dampening=0.0,
                                   nesterov=c.nesterov, maximize=False,
                                   is_first_step=False)  # fmt: skip
                    else:  # torch.optim.SGD's foreach steps
                        bs = [self.buffers[n][idx] for n in names]
                        torch._foreach_mul_(bs, m)
                        torch._foreach_add_(bs, gs)
                        ds = torch._foreach_add(gs, bs, alpha=m) if c.nesterov else bs
                        torch._foreach_add_(ps, ds, alpha=-(lr * scale))

    def _done(self, i: int) -> bool:
        return self.runs[i].step >= self.runs[i].config.steps

    # ------------------------------------------------------------------ one step of all runs
    def _forward(self, objects: torch.Tensor):
        """One episode of every active run: objects ``(N, B)`` -> the stacked episode tensors."""
        runs = [self.runs[i] for i in self.active]
        n, batch = objects.shape
        agent = self._template
        glances = agent.config.glances
        q = torch.stack(
            [uniform_locations(batch, r.policy_generator, objects.device) for r in runs]
        )  # the first glance: random (the paper)
        state = None  # the core's initial state (LSTMCore's zeros)
        locations, logits, baselines, mus, sigmas = [], [], [], [], []
        flat_objects = objects.reshape(-1)
        for s in range(glances):
            # one lookup of N * B glances: a glance depends only on its object and pose
            pressure = _pressure(runs, flat_objects, q)
            final = s == glances - 1
            state, lg, b, dist = self._net.glance(self.stacked, pressure, q, state, not final)
            locations.append(q)
            logits.append(lg)
            baselines.append(b)
            if final:
                break
            if dist:
                mus.append(dist[0])
                sigmas.append(dist[1])
                # each run's draws from its own generator (as TruncatedGaussian.sample draws
                # them), the inverse-CDF transform once for all runs
                u = torch.stack([torch.rand(dist[0].shape[1:], generator=r.policy_generator,
                                            dtype=torch.float64, device=objects.device)
                                 for r in runs])  # fmt: skip
                q = truncated_normal(dist[0], dist[1], uniform=u)
            else:
                q = torch.stack(
                    [Uniform((batch,), objects.device).sample(r.policy_generator) for r in runs]
                )
        mu = torch.stack(mus, 1) if mus else None
        sigma = torch.stack(sigmas, 1) if sigmas else None
        return (
            torch.stack(locations, 1),
            torch.stack(logits, 1),
            torch.stack(baselines, 1),
            mu,
            sigma,
        )

    def _losses(self, objects, locations, logits, baselines, mu, sigma):
        """Each active run's hybrid loss (:func:`ham.learn.hybrid_loss.hybrid_loss`, mapped
        over the runs): ``(total, reward, classification, reinforce, baseline)``, each ``(N,
        ...)``. Runs of other loss reductions are mapped apart (a reduction is code, not a
        number), each with its own beta."""
        runs = [self.runs[i] for i in self.active]
        glances = runs[0].config.model.glances
        kinds = _grouped(range(len(runs)), lambda k: (runs[k].config.classification_reduction,
                                                      runs[k].config.reinforce_reduction))  # fmt: skip
        args = (objects, locations, logits, baselines, mu, sigma)
        if len(kinds) == 1:
            ((reductions, ks),) = kinds.items()
            return self._mapped_loss(glances, reductions, [runs[k] for k in ks], *args)
        out = [None] * len(runs)
        for reductions, ks in kinds.items():
            idx = torch.tensor(ks, device=objects.device)
            part = [None if a is None else a.index_select(0, idx) for a in args]
            parts = self._mapped_loss(glances, reductions, [runs[k] for k in ks], *part)
            for j, k in enumerate(ks):
                out[k] = [x[j] for x in parts]
        return tuple(torch.stack(xs) for xs in zip(*out, strict=True))

    @staticmethod
    def _mapped_loss(glances, reductions, runs, objects, locations, logits, baselines, mu,
                     sigma):  # fmt: skip
        """:func:`hybrid_loss` of ``runs`` (one pair of reductions), mapped over them."""
        # one beta for the runs: the number itself; else each run's, mapped with its episode
        betas = [r.config.beta for r in runs]
        beta = torch.tensor(betas, dtype=logits.dtype, device=logits.device)
        one = len(set(betas)) == 1

        def loss(objects, locations, logits, baselines, mu, sigma, beta):
            if glances == 1:
                policy = None
            elif mu is None:
                policy = Uniform((glances - 1, objects.shape[0]), objects.device)
            else:
                policy = TruncatedGaussian(mu, sigma)
            episode = Episode(objects, locations, logits, baselines, policy)
            h = hybrid_loss(episode, betas[0] if one else beta, *reductions)
            return h.total, h.reward, h.classification, h.reinforce, h.baseline

        if mu is None:
            return torch.vmap(lambda o, lo, lg, b, be: loss(o, lo, lg, b, None, None, be))(
                objects, locations, logits, baselines, beta
            )
        return torch.vmap(loss)(objects, locations, logits, baselines, mu, sigma, beta)

    def step(self) -> list[tuple]:
        """One training step of every active run (:func:`ham.learn.train.train_step` for N).

        Returns ``(run index, loss, mean reward, [classification, reinforce, baseline])`` of
        the runs that stepped; a run whose loss or
        weights are not finite leaves the group with its error recorded."""
        runs = [self.runs[i] for i in self.active]
        for r in runs:  # as train_step: the run's optimizer (its checkpoint) holds its rates
            for group in r.optimizer.param_groups:
                group["lr"] = r.config.learning_rate(r.step) * group.get("lr_scale", 1.0)
        objects = torch.stack([r.env.sample_objects() for r in runs])
        self._net.begin(self.stacked)
        totals, rewards, *parts = self._losses(objects, *self._forward(objects))
        if not self._checked:  # a weight the stacked layers skip would silently never train
            unused = set(self._names) - self._net.used
            if self._template.config.glances == 1:  # no glance is chosen by the policy
                unused = {n for n in unused if not n.startswith("location.")}
            if unused:
                raise HamError(f"the batched layers do not read the weights {sorted(unused)}; "
                               "train this model with ham train or --executor local")  # fmt: skip
            self._checked = True
        finite = torch.isfinite(totals).tolist()
        failed = []
        for k, ok in enumerate(finite):
            if not ok:
                try:
                    _check_loss(runs[k], totals[k])
                except HamError as exc:
                    self.results[self.active[k]] = str(exc)
                failed.append(self.active[k])
        mask = torch.tensor(finite, device=totals.device)
        torch.where(mask, totals, torch.zeros_like(totals)).sum().backward()
        grads = self._net.grads()  # None of a layer unused (one glance: the location heads)
        stepping = [k for k in range(len(runs)) if finite[k]]
        if self._sgd:
            self._sgd_step(runs, stepping, grads)
        else:
            for k in stepping:
                r, params = runs[k], self._params[self.active[k]]
                for name, p in params.items():
                    p.grad = grads[name][k] if name in grads else None
                r.optimizer.step()
                for p in params.values():
                    p.grad = None
        for k in stepping:
            runs[k].step += 1
        # the weights of all runs in one reduction (one sync on a GPU), as _check_weights does
        with torch.no_grad():
            sums = torch.stack([v.reshape(len(runs), -1).sum(1) for v in self.stacked.values()])
            weights_ok = torch.isfinite(sums.sum(0)).tolist()
        out = []
        for k, r in enumerate(runs):
            if not finite[k]:
                continue
            if not weights_ok[k]:
                try:
                    _check_weights(r)  # the message, with the first weight named
                except HamError as exc:
                    self.results[self.active[k]] = str(exc)
                failed.append(self.active[k])
                continue
            out.append((self.active[k], totals[k].detach(), rewards[k].mean(),
                        [x[k].detach() for x in parts]))  # fmt: skip
        if failed:
            self._drop(failed)
        return out

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
                                         self.runs[i].config.eval_policy))  # fmt: skip
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
        first = torch.empty(n, batches, batch, 2, device=device)
        draws = torch.empty(n, batches, later, batch, 2, device=device, dtype=dtype)
        for j, r in enumerate(runs):
            g = torch.Generator(device=device)
            g.manual_seed(stream_seed(r.config.seed, 2))
            for b in range(batches):
                torch.rand(batch, 2, generator=g, device=device, out=first[j, b])
                for s in range(later):
                    torch.rand(batch, 2, generator=g, device=device, dtype=dtype,
                               out=draws[j, b, s])  # fmt: skip
        correct = torch.zeros(n, glances, device=device)
        accumulated = torch.zeros(n, glances, device=device)
        confusion = torch.zeros(n * glances * k * k, dtype=torch.long, device=device)
        offsets = (torch.arange(n, device=device).view(-1, 1, 1) * glances
                   + torch.arange(glances, device=device).view(1, -1, 1)) * (k * k)  # fmt: skip
        counts = torch.arange(1, glances + 1, device=device).view(1, -1, 1, 1)
        mu_sum = torch.zeros(n, k, 2, device=device, dtype=torch.float64)
        n_obj = torch.zeros(k, device=device, dtype=torch.float64)
        path = torch.zeros(n, device=device, dtype=torch.float64)
        per = max(1, _EVAL_ROWS // batch)  # batches per pass
        for b0 in range(0, batches, per):
            b1 = min(batches, b0 + per)
            rows = (b1 - b0) * batch
            objects = torch.cat([env.balanced_objects(b) for b in range(b0, b1)])
            flat_objects = objects.expand(n, rows).reshape(-1)
            q = first[:, b0:b1].reshape(n, rows, 2) * 2 - 1  # uniform_locations
            state = None  # the core's initial state
            locations, logits, mode = [], [], None
            for s in range(glances):
                pressure = _pressure(runs, flat_objects, q)
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
            if mode is not None:
                mu_sum.index_add_(1, objects, mode.double())
                n_obj += torch.bincount(objects, minlength=k)
        confusion = confusion.view(n, -1)
        return [eval_result(env, batches, correct[j], accumulated[j], confusion[j], mu_sum[j],
                            n_obj, path[j]) for j in range(n)]  # fmt: skip

    def _evaluate(self, due: list[tuple[int, float | None, float | None]]) -> dict[int, dict]:
        """Evaluate and record the runs ``due`` (run index, mean train loss and reward since
        the last evaluation), as :func:`ham.learn.train._evaluate`; their records by index."""
        if not due:
            return {}
        results = self.evaluate([i for i, _, _ in due])
        return {i: _evaluate(self.runs[i], loss, reward, result)
                for (i, loss, reward), result in zip(due, results, strict=True)}  # fmt: skip

    # ------------------------------------------------------------------ the loop
    def train(self, progress: bool = False) -> list[dict | str]:
        """Train every run to its ``steps`` (:func:`ham.learn.train.train_loop` for N).

        Returns per run its metrics, or the one-line error that stopped it."""
        from torch.utils.tensorboard import SummaryWriter
        from tqdm.auto import tqdm

        for r, out in zip(self.runs, self.outs, strict=True):
            out.mkdir(parents=True, exist_ok=True)
            _write_json(out / CONFIG_FILE, r.config.to_dict())
        writers = {}
        sums = {}
        for i, record in self._evaluate(
            [
                (i, None, None)
                for i in self.active
                if self.runs[i].step == 0 and not self.runs[i].history
            ]  # fmt: skip
        ).items():
            writers[i] = SummaryWriter(str(self.outs[i] / "tb"))
            _log_eval(writers[i], record, self.runs[i].config.model.glances)
            self._save(i)
            self._maybe_stop(i)
        for i in list(self.active):
            r, out = self.runs[i], self.outs[i]
            if i not in writers:
                writers[i] = SummaryWriter(str(out / "tb"), purge_step=r.step or None)
            sums[i] = [
                torch.zeros((), device=r.env.device),
                torch.zeros((), device=r.env.device),
                0,
            ]
        if self.stopped:
            self._drop([i for i in self.stopped if i in self.active])
        total = sum(self.runs[i].config.steps - self.runs[i].step for i in self.active)
        bar = tqdm(
            total=total, disable=not progress, unit="step", desc=f"train x{len(self.active)}"
        )
        t_train, n_train = 0.0, 0
        try:
            while self.active:
                t0 = time.perf_counter()
                stepped = self.step()
                t_train += time.perf_counter() - t0
                n_train += 1
                bar.update(len(stepped))
                finished, due = [], []
                for i, loss, reward, parts in stepped:
                    r, c, w, acc = self.runs[i], self.runs[i].config, writers[i], sums[i]
                    acc[0] += loss
                    acc[1] += reward
                    acc[2] += 1
                    if r.step % c.log_every == 0:
                        w.add_scalar("train/loss", loss.item(), r.step)
                        for name, x in zip(_PARTS, parts, strict=True):
                            w.add_scalar(f"train/{name}", x.item(), r.step)
                        w.add_scalar("train/reward", reward.item(), r.step)
                        w.add_scalar("train/lr", r.optimizer.param_groups[0]["lr"], r.step)
                    if r.step % c.eval_every == 0 or r.step == c.steps:
                        due.append((i, acc[0].item() / acc[2], acc[1].item() / acc[2]))
                        acc[0].zero_()
                        acc[1].zero_()
                        acc[2] = 0
                for i, record in self._evaluate(due).items():  # the due runs at once
                    _log_eval(writers[i], record, self.runs[i].config.model.glances)
                    self._save(i)
                    if self._maybe_stop(i):
                        finished.append(i)
                for i, *_ in stepped:
                    if self._done(i):
                        finished.append(i)
                if finished:
                    self._drop(sorted(set(finished)))
        finally:
            bar.close()
            for w in writers.values():
                w.close()
        for i in writers:
            if n_train:
                _write_json(
                    self.outs[i] / TIMING_FILE,
                    {"steps_timed": n_train, "ms_per_step": 1000 * t_train / n_train,
                     "batched_runs": len(self.runs), "torch_threads": torch.get_num_threads(),
                     "device": self.runs[i].config.device},
                )  # fmt: skip
        return [self.results.get(i, None) or self.metrics(i) for i in range(len(self.runs))]

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
        _write_atomic(self.outs[i] / CHECKPOINT_FILE, lambda p: torch.save(state, p))
        _write_json(self.outs[i] / METRICS_FILE, self.metrics(i))


# --------------------------------------------------------------------------- entry points
def _open_runs(configs: list[TrainConfig], outs: list[Path]) -> list[Run]:
    """The runs of ``configs`` with one shared glance source; a directory holding a checkpoint
    is resumed from it (its config.json, to the given ``steps``)."""
    if not configs:
        raise HamError("no runs to batch; accepted: one config or more")
    if len(configs) != len(outs):
        raise HamError(f"{len(configs)} configs but {len(outs)} directories; give one each")
    if len({str(o.resolve()) for o in outs}) != len(outs):
        raise HamError("two runs of one batch share a directory; give each its own")
    for c in configs:
        check_batchable(c)
    keys = {shape_key(c) for c in configs}
    if len(keys) > 1:
        raise HamError(
            "the batched runs differ in more than " + ", ".join(PER_RUN) + "; accepted: "
            "configs of one shape (a beta of 0 is a shape of its own)"
        )
    c0 = configs[0]
    device = torch.device(c0.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise HamError("device 'cuda' requested but CUDA is not available; use --device cpu")
    source, _ = make_source(c0.table, c0.world, device)
    check_model_fits(c0.model.pressure_dim, c0.model.n_objects, source)
    runs: list[Run] = []
    for c in configs:
        env = HapticEnv(source, c.batch_size, c.normalization, stream_seed(c.seed, 0), device)
        runs.append(Run.create(c, env))
    return runs


def train_batched(
    configs: list[TrainConfig],
    outs: list[str | os.PathLike],
    *,
    stop_at_perfect: bool = False,
    progress: bool = False,
) -> list[dict | str]:
    """Train fresh runs ``configs`` into ``outs`` as one batch, or continue those whose
    directory holds a checkpoint (to the config's ``steps``). Returns per run its metrics (also
    in its metrics.json), or the one-line error that stopped it (NaN/inf)."""
    outs = [Path(o) for o in outs]
    configs = list(configs)
    resumed = []
    for k, (c, out) in enumerate(zip(configs, outs, strict=True)):
        if (out / CHECKPOINT_FILE).exists():
            saved = TrainConfig.from_dict(read_json(out / CONFIG_FILE))
            # where it runs (device, table path) may change between invocations, as on resume
            saved = replace(saved, steps=c.steps, device=c.device, table=c.table)
            if not _same_run(saved, c):
                raise HamError(
                    f"{str(out)!r} holds another run (seed {saved.seed}); accepted: the same "
                    "config, or an empty directory"
                )
            configs[k] = saved
            resumed.append(k)
    runs = _open_runs(configs, outs)
    for k in resumed:
        runs[k].load_state_dict(load_checkpoint(outs[k]))
        if runs[k].step > configs[k].steps:
            raise HamError(f"the run in {str(outs[k])!r} is at step {runs[k].step}, beyond "
                           f"steps {configs[k].steps}")  # fmt: skip
    stopped = {k: s for k, out in enumerate(outs) if (s := _stopped_at(out)) is not None}
    group = BatchedRuns(runs, outs, stop_at_perfect, stopped)
    try:
        return group.train(progress)
    finally:
        for r in runs:
            r.close()


def _stopped_at(out: Path) -> int | None:
    """The step a run stopped at with a perfect evaluation (``None``: it did not)."""
    try:
        return json.loads((out / METRICS_FILE).read_text()).get(STOPPED_KEY)
    except (OSError, ValueError):
        return None
