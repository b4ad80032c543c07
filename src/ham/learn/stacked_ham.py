"""The HAM over N runs' stacked weights: one glance of N runs as one pass (batched training).

:class:`StackedHam` mirrors :mod:`ham.model` line by line over weights stacked along a leading run
axis, ``(N, B, ...)`` in and out; :class:`ham.learn.batched.BatchedRuns` trains N runs through it.
What makes a step of N runs cheaper than N steps of one (docs/batched.md has the
measurements):

- the products (:func:`_mm_nt`): one ``bmm`` for all runs (on an AMD CPU with AVX-512 each large
  product is one oneDNN call per run), the layers reading the core's output joined into one layer
  (:meth:`StackedHam._heads`), and from 6 glances on the CPU the gates' forward as two products of
  half the outputs (:meth:`_Layer.split_forward`);
- deferred weight gradients: each layer (:class:`_Layer`) records its inputs and output gradients
  over the glances and makes its weight gradient as one product per run after the backward pass,
  and so is the tactile network's whole backward (concat combiners:
  :meth:`StackedHam._tactile_backward`; on the CPU each of its ReLUs writes straight into the
  record the next layer reads, and ``[g, h]`` is never joined: :meth:`_Layer.slot`);
- the LSTM cell fused (:class:`_TanhLSTMCell`, its backward compiled on the CPU).
"""

from __future__ import annotations

import contextlib
import warnings

import torch
from torch.nn import functional as F

from ham.errors import HamError
from ham.model.agent import HamConfig
from ham.world.devices import cpu_info


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
# The CPU products' path, by what was measured (docs/batched.md): MKL, torch's BLAS,
# picks its kernels by the CPU's vendor. On an AMD CPU with AVX-512 it runs AVX2 kernels, and
# one oneDNN product per run (AVX-512) is twice as fast as its batched bmm; on Intel it runs
# AVX-512 kernels, and on an AMD CPU without AVX-512 both have only AVX2: there its bmm makes
# the batched step 1.2-1.3x faster than oneDNN per run. Fixed per machine, so a run resumed on
# the same machine takes the same path (bit-identical resume).
_AMD = cpu_info("vendor_id") == "AuthenticAMD"
_PER_RUN_ONEDNN = _AMD and "avx512f" in cpu_info("flags").split()
# tanh in the LSTM cell as 2 sigmoid(2x) - 1 (:class:`_TanhLSTMCell`): on AMD, where
# torch.tanh is slow (with AVX-512 or without: 0.6 ms against 0.25 on 10 x 64 x 256);
# fixed per machine as the products' path
_SIGMOID_TANH = _AMD
# smaller layers (poses in, heads out, 256 -> 64): one bmm beats N small calls (measured)
_ONEDNN_MIN = 128 * 256
# The forward of a layer with this many outputs (the LSTM's gates: 1024), in a step of at least
# _SPLIT_GLANCES glances, as two products of half the outputs on a transposed copy of the
# weights made once per step (:meth:`_Layer.split_forward`). On an Intel Xeon (1.25 MiB of L2
# per core) MKL's product of 1024 outputs (a 2 MB panel of weights) takes 7.2 ms for 10 runs,
# two of 512 on contiguous halves 5.5 ms (at the paper's batch of 64 their outputs were the
# same to the bit; in general the same to float rounding); the transpose costs 7.8 ms a step,
# so it pays from 6 glances (docs/batched.md, the step's time against one product:
# 0.97x at 10 and 8 glances, 0.98x at 6, 1.00x at 4, 1.05x at 3).
_SPLIT_OUTPUTS = 1024
_SPLIT_GLANCES = 6


def _mm_nt(a: torch.Tensor, b: torch.Tensor, bias: torch.Tensor | None = None) -> torch.Tensor:
    """``a[k] @ b[k]^T (+ bias[k])`` for every run ``k``: ``a (N, M, K)``, ``b (N, P, K)``,
    either possibly a transposed view (never copied: a transposing copy costs more than the
    product).

    On an AMD CPU with AVX-512 in fp32 (:data:`_PER_RUN_ONEDNN`), one oneDNN product per run:
    MKL's sgemm runs its AVX2 kernels there, oneDNN's AVX-512 kernels are twice as fast, and
    MKL's batched ``bmm`` is no faster than a loop of single products. Elsewhere (Intel: MKL's
    AVX-512 kernels; AMD without AVX-512: AVX2 either way; CUDA: one launch for all runs) one
    ``bmm``, the bias added in place on the CPU
    (``baddbmm`` first copies the broadcast bias into the output: 10.2 vs 8.7 ms for the LSTM's
    gates of 10 runs) and by ``baddbmm`` on a GPU (docs/batched.md)."""
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
        device and dtype): an input written straight into it (:meth:`StackedHam.glance`'s
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
# runs at the paper's size on an Intel Xeon), compiled one (0.7 ms): docs/batched.md.
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
    layer's bias holds it, :meth:`StackedHam.glance`), with a hand-written backward
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
    its gradient is recorded (:meth:`StackedHam._record_dg`) and the tactile network's
    backward runs once for all glances after the backward pass
    (:meth:`StackedHam._tactile_backward`). ``anchor`` (a stacked weight) only gives the node
    an input that requires a gradient."""

    @staticmethod
    def forward(ctx, g, anchor, net, slot):
        ctx.net, ctx.slot = net, slot
        return g.view_as(g)

    @staticmethod
    def backward(ctx, dg):
        ctx.net._record_dg(ctx.slot, dg)
        return None, None, None, None


class StackedHam:
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
