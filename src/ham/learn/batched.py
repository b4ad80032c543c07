"""Batched training: N runs of one shape trained as one stacked model (beyond the paper).

The paper's grid is hundreds of small runs (LSTM 256, batch 64); one run at a time leaves the
matrix units idle. Here N runs whose configs differ only in ``seed`` (and ``steps``) share every
matrix product: their weights are stacked along a leading run axis and one glance of all N runs
is one :func:`torch.vmap` of the HAM's own modules (:func:`torch.func.functional_call`), the
hybrid loss likewise; one backward yields every run's gradient (the runs' graphs are disjoint).

Everything else stays per run and is the single run's own code (:mod:`ham.learn.train`): each
run is a :class:`ham.learn.train.Run` with its own environment generator (objects, stream 0),
pose generator (stream 1), optimizer (SGD with Nesterov momentum at its own learning-rate
schedule), evaluation (stream 2), checkpoint, ``config.json``, ``metrics.json``, ``timing.json``
and ``tb/``. A run's parameters are views into the stacked tensors, so its optimizer steps them
in place and its evaluation reads the current weights. The same seed gives the single run's
numbers to float tolerance (the batched products sum in another order); resume is bit-identical
to an uninterrupted batched group. A run whose loss or weights turn NaN/inf stops alone (its
directory keeps its last checkpoint), the others go on. With ``stop_at_perfect`` a run whose
best evaluation reaches 1.0 stops (its best accuracy can no longer change); its metrics say
``"stopped_at_perfect": step``.

Only the hybrid learner on the haptic world with a random first glance is batched; anything
else is refused with one line (train it with ``ham train`` or ``--executor local``).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import replace
from pathlib import Path

import torch
from torch.nn import functional as F

from ham.errors import HamError
from ham.learn.environment import HapticEnv
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
from ham.model.location_net import uniform_locations
from ham.model.policy import TruncatedGaussian, Uniform
from ham.world.source import check_model_fits, make_source

STOPPED_KEY = "stopped_at_perfect"
_PARTS = ("classification", "reinforce", "baseline_loss")  # TensorBoard, as train_loop


def shape_key(config: TrainConfig) -> str:
    """Runs with equal keys can share one batched model: the config without seed and steps."""
    d = config.to_dict()
    d.pop("seed")
    d.pop("steps")
    return json.dumps(d, sort_keys=True)


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


class _Linear(torch.autograd.Function):
    """``y = x W^T + b`` for N runs at once: ``x (N, B, in)``, ``W (N, out, in)``, ``b (N, out)``.

    By hand rather than through :func:`torch.vmap` of ``nn.Linear``: the weight gradient comes
    out as one ``bmm`` in ``W``'s own layout (vmap's is transposed, then copied: on the CPU that
    copy and the slower transposed product cost as much as the batching saves)."""

    @staticmethod
    def forward(ctx, x, weight, bias):
        ctx.save_for_backward(x, weight)
        ctx.has_bias = bias is not None
        wt = weight.transpose(1, 2)
        return torch.bmm(x, wt) if bias is None else torch.baddbmm(bias.unsqueeze(1), x, wt)

    @staticmethod
    def backward(ctx, grad):
        x, weight = ctx.saved_tensors
        gx = torch.bmm(grad, weight) if ctx.needs_input_grad[0] else None
        gw = torch.bmm(grad.transpose(1, 2), x) if ctx.needs_input_grad[1] else None
        gb = grad.sum(1) if ctx.has_bias and ctx.needs_input_grad[2] else None
        return gx, gw, gb


class _StackedHam:
    """The HAM's layers (:mod:`ham.model`) over weights stacked along a leading run axis: one
    glance of N runs, ``(N, B, ...)`` in and out. Each line mirrors its module (tactile network,
    core, classifier, baseline, location network), detaches included."""

    def __init__(self, config: HamConfig) -> None:
        self.c = config
        self.used: set[str] = set()  # the weights read: checked against the model's once

    def _lin(self, p: dict, name: str, x: torch.Tensor) -> torch.Tensor:
        self.used.add(name + ".weight")
        if name + ".bias" in p:
            self.used.add(name + ".bias")
        return _Linear.apply(x, p[name + ".weight"], p.get(name + ".bias"))

    def glance(self, p: dict, pressure, q, state, with_policy: bool):
        c = self.c
        # HapticAttentionModel.step: the pose fed to the tactile network
        location = torch.stack([q[..., 0], q[..., 1] * c.phi_scale], dim=-1)
        # TactileNetwork
        what = torch.relu(self._lin(p, "tactile.what", pressure))
        where = torch.relu(self._lin(p, "tactile.where", location))
        if c.combiner == "add":
            g = what + where
        elif c.combiner == "mul":
            g = what * where
        else:
            g = torch.cat([what, where], dim=-1)
            for k in range(2 if c.combiner == "concat2" else 1):
                g = torch.relu(self._lin(p, f"tactile.combine.{2 * k}", g))
        # the core: LSTMCore or MLPCore
        if c.core == "lstm":
            h, cell = state
            if c.truncate_bptt:
                h, cell = h.detach(), cell.detach()
            act = torch.tanh if c.lstm_activation == "tanh" else torch.relu
            i, f, u, o = self._lin(p, "core.gates", torch.cat([g, h], dim=-1)).chunk(4, dim=-1)
            cell = torch.sigmoid(f + c.forget_bias) * cell + torch.sigmoid(i) * act(u)
            tau = torch.sigmoid(o) * act(cell)
            state = (tau, cell)
        else:
            tau = torch.relu(self._lin(p, "core.dense", g))
        logits = self._lin(p, "classifier.dense", tau)
        baseline = self._lin(p, "baseline.dense", tau.detach()).squeeze(-1)
        dist = None
        if with_policy and c.policy == "learned":  # LocationNetwork: reads tau detached
            t = tau.detach()
            mu = torch.tanh(self._lin(p, "location.mu", t))
            s = self._lin(p, "location.sigma", t)
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
        self._template = self.runs[0].agent  # its config and initial state only
        self._net = _StackedHam(self._template.config)
        self._names = [n for n, _ in self.runs[0].agent.named_parameters()]
        self._checked = False
        if self.active:
            self._stack()

    # ------------------------------------------------------------------ stacked weights
    def _stack(self) -> None:
        """Stack the active runs' weights and make each run's parameters views of the stack."""
        self.stacked: dict[str, torch.Tensor] = {}
        params = [dict(self.runs[i].agent.named_parameters()) for i in self.active]
        for name in self._names:
            big = torch.stack([p[name].detach() for p in params])
            for k, p in enumerate(params):
                p[name].data = big[k]
            self.stacked[name] = big.detach().requires_grad_()

    def _drop(self, gone: list[int]) -> None:
        """Take runs out of the group (finished, diverged, stopped); the others go on."""
        self.active = [i for i in self.active if i not in gone]
        for i in gone:  # its own compact copy of the weights, apart from the stack
            for p in self.runs[i].agent.parameters():
                p.data = p.data.clone()
        if self.active:
            self._stack()

    def _done(self, i: int) -> bool:
        return self.runs[i].step >= self.runs[i].config.steps

    # ------------------------------------------------------------------ one step of all runs
    def _forward(self, objects: torch.Tensor):
        """One episode of every active run: objects ``(N, B)`` -> the stacked episode tensors."""
        runs = [self.runs[i] for i in self.active]
        n, batch = objects.shape
        agent = self._template
        glances = agent.config.glances
        env = runs[0].env
        q = torch.stack(
            [uniform_locations(batch, r.policy_generator, objects.device) for r in runs]
        )  # the first glance: random (the paper)
        state = tuple(
            t.unsqueeze(0).repeat(n, *([1] * t.dim())) for t in agent.core.initial_state(batch, q)
        )
        locations, logits, baselines, mus, sigmas = [], [], [], [], []
        flat_objects = objects.reshape(-1)
        for s in range(glances):
            # one lookup of N * B glances: a glance depends only on its object and pose
            pressure = env.glance(flat_objects, q.reshape(-1, 2)).view(n, batch, -1)
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
                qs = [TruncatedGaussian(dist[0][k], dist[1][k]).sample(r.policy_generator)
                      for k, r in enumerate(runs)]  # fmt: skip
            else:
                qs = [Uniform((batch,), objects.device).sample(r.policy_generator) for r in runs]
            q = torch.stack(qs)
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
        c = self.runs[self.active[0]].config
        glances = c.model.glances

        def loss(objects, locations, logits, baselines, mu, sigma):
            if glances == 1:
                policy = None
            elif mu is None:
                policy = Uniform((glances - 1, objects.shape[0]), objects.device)
            else:
                policy = TruncatedGaussian(mu, sigma)
            episode = Episode(objects, locations, logits, baselines, policy)
            h = hybrid_loss(episode, c.beta, c.classification_reduction, c.reinforce_reduction)
            return h.total, h.reward, h.classification, h.reinforce, h.baseline

        if mu is None:
            return torch.vmap(lambda o, lo, lg, b: loss(o, lo, lg, b, None, None))(
                objects, locations, logits, baselines
            )
        return torch.vmap(loss)(objects, locations, logits, baselines, mu, sigma)

    def step(self) -> list[tuple]:
        """One training step of every active run (:func:`ham.learn.train.train_step` for N).

        Returns ``(run index, loss, mean reward, [classification, reinforce, baseline])`` of
        the runs that stepped; a run whose loss or
        weights are not finite leaves the group with its error recorded."""
        runs = [self.runs[i] for i in self.active]
        for r in runs:
            for group in r.optimizer.param_groups:
                group["lr"] = r.config.learning_rate(r.step)
        objects = torch.stack([r.env.sample_objects() for r in runs])
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
        for v in self.stacked.values():
            v.grad = None
        torch.where(mask, totals, torch.zeros_like(totals)).sum().backward()
        for k, r in enumerate(runs):
            if not finite[k]:
                continue
            for name, p in r.agent.named_parameters():
                grad = self.stacked[name].grad  # None: unused (one glance: the location heads)
                p.grad = None if grad is None else grad[k]
            r.optimizer.step()
            for p in r.agent.parameters():
                p.grad = None
            r.step += 1
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
        for i in list(self.active):
            r, out = self.runs[i], self.outs[i]
            writers[i] = SummaryWriter(str(out / "tb"), purge_step=r.step if r.step else None)
            if r.step == 0 and not r.history:
                _log_eval(writers[i], _evaluate(r, None, None), r.config.model.glances)
                self._save(i)
                self._maybe_stop(i)
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
                finished = []
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
                        record = _evaluate(r, acc[0].item() / acc[2], acc[1].item() / acc[2])
                        acc[0].zero_()
                        acc[1].zero_()
                        acc[2] = 0
                        _log_eval(w, record, c.model.glances)
                        self._save(i)
                        if self._maybe_stop(i):
                            finished.append(i)
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
            "the batched runs differ in more than seed and steps; accepted: configs of one shape"
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
            if shape_key(saved) != shape_key(c) or saved.seed != c.seed:
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
