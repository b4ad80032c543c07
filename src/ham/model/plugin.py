"""Plugins: the user's own cores, location policies and learners, from a Python file (``--plugin``).

A plugin is a self-contained Python file that registers cores (:func:`ham.model.core.register_core`),
location policies (:func:`ham.model.policy.register_policy`) and learners
(``ham.learn.learners.register_learner``, a registry the learn layer adds with
:func:`add_registry`); ``ham train --plugin FILE.py --core NAME`` / ``--policy NAME`` /
``--learner NAME`` then trains with them, and nothing in the package is edited. A
run keeps the file's record (name, sha256, text: :attr:`ham.model.agent.HamConfig.plugin`), so
``ham evaluate``, ``ham heatmap``, ``--resume`` and reproduce's workers register the same code
again wherever they load the run. Objects belong in an objects file (``--objects-file``,
:mod:`ham.world.objects`), which a world records; a plugin that registers objects is refused.
"""

from __future__ import annotations

import copy
from pathlib import Path

import torch
from torch import nn

from ham.errors import HamError, with_article
from ham.model.core import CORES
from ham.model.policy import POLICIES, LocationDistribution
from ham.world import recorded_file, registering

SUFFIXES: tuple[str, ...] = (".py",)
#: What a plugin may register, by label: cores and policies here; an upper layer adds its own
#: registry when it is imported (:func:`add_registry`; ``ham.learn.learners``: ``learner``), so
#: that imports point down the layers.
REGISTRIES: dict[str, dict] = {"core": CORES, "policy": POLICIES}
#: label -> the names a registry holds before any plugin (its built-in ones)
BUILTIN_CORES: tuple[str, ...] = tuple(CORES)
BUILTIN_POLICIES: tuple[str, ...] = tuple(POLICIES)
_BUILTIN: dict[str, tuple[str, ...]] = {"core": BUILTIN_CORES, "policy": BUILTIN_POLICIES}
#: label -> how a plugin registers one (for the error of a plugin that registers nothing; the
#: learners' too before ham.learn is imported)
_HOW: dict[str, str] = {
    "core": "ham.model.core.register_core",
    "policy": "ham.model.policy.register_policy",
    "learner": "ham.learn.learners.register_learner",
}
#: sha256 -> the names the plugin registered: a process runs each plugin once.
_LOADED: dict[str, tuple[str, ...]] = {}


def read_plugin(path: str | Path) -> dict:
    """The record of the plugin file ``path``: ``{"name", "sha256", "source"}`` (nothing runs)."""
    return recorded_file.read_record(
        path, "plugin", SUFFIXES, "a .py file that registers cores or location policies"
    )


def check_plugin(record: object) -> dict:
    """``record`` if it is a complete plugin record whose text has its sha256, else an error."""
    return recorded_file.check_record(record, "plugin", "plugin", SUFFIXES)


def load_plugin(record: dict) -> list[str]:
    """Run the plugin of ``record`` (verified) once per process; returns what it registered
    (``core NAME``, ``policy NAME``).

    A plugin that fails, registers nothing, or registers objects leaves the registries as they were.
    """
    record = check_plugin(record)
    sha = record["sha256"]
    if sha in _LOADED:
        return list(_LOADED[sha])
    # the learners' registry joins REGISTRIES when the plugin imports ham.learn: live, and a
    # registry that joins while the plugin runs counts only what it adds (_BUILTIN)
    how = list(_HOW.values())
    got = registering.run_registering(
        "plugin", record, "ham_plugin", REGISTRIES, "no core, location policy or learner",
        f"a file that calls {', '.join(how[:-1])} or {how[-1]}", builtin=_BUILTIN,
    )  # fmt: skip
    added = [f"{label} {n}" for label, names in got.items() for n in names]
    _LOADED[sha] = tuple(added)
    return list(added)


def add_registry(label: str, registry: dict, how: str) -> None:
    """Let plugins register into ``registry`` (an upper layer's, e.g. the learners') under
    ``label``; ``how``: the function they call. Its names now are its built-in ones."""
    REGISTRIES[label] = registry
    _BUILTIN[label] = tuple(registry)
    _HOW[label] = how


# ------------------------------------------------------------------ the parts a plugin builds
def _file_of(part) -> str:
    """The file whose code defines ``part`` (a factory function or a class): for a plugin, the
    name its text was compiled under; ``'?'`` when none is found."""
    candidates = [part] if not isinstance(part, type) else list(vars(part).values())
    for c in candidates:
        code = getattr(getattr(c, "__func__", c), "__code__", None)
        if code is not None:
            return code.co_filename
    return "?"


def build_part(label: str, name: str, registry: dict, make, *args, **kwargs):
    """``make(*args, **kwargs)``, the ``label`` ("core", "policy") ``name`` built; for one that is
    not built in, any failure of the user's code is one line naming its file and line."""
    if name in _BUILTIN[label] or name not in registry:
        return make(*args, **kwargs)
    return recorded_file.call(
        f"{label} {name!r} of", _file_of(registry[name]), make, *args, **kwargs
    )


def shape_text(x) -> str:
    """A tensor's shape, else what ``x`` is ("an int", "a tuple")."""
    if isinstance(x, torch.Tensor):
        return str(tuple(x.shape))
    return with_article(type(x).__name__)


def check_core(name: str, core, input_size: int, hidden_size: int) -> None:
    """A core that is not built in keeps the contract the model relies on (:data:`CORES`): a
    module whose ``initial_state(batch, like)`` and ``forward(g, state) -> (tau, state)`` give
    ``tau`` of ``hidden_size`` features for each episode. Tried on a copy for two steps of two
    episodes, under a forked random state: the core and the run's random numbers are as before."""
    if name in _BUILTIN["core"]:
        return
    file = _file_of(CORES[name])
    label = f"core {name!r} of"  # recorded_file.call adds the file
    what = f"{label} {file!r}"
    if not (isinstance(core, nn.Module) and callable(getattr(core, "initial_state", None))):
        raise HamError(
            f"{what} built {shape_text(core)}; accepted: a torch.nn.Module with initial_state(batch, "
            "like) and forward(g, state) -> (tau, state)"
        )
    with torch.random.fork_rng(devices=[]), torch.no_grad():
        trial = copy.deepcopy(core)
        g = torch.zeros(2, input_size)
        state = recorded_file.call(label, file, trial.initial_state, 2, g)
        for _ in range(2):
            out = recorded_file.call(label, file, trial, g, state)
            if not (isinstance(out, tuple) and len(out) == 2):
                raise HamError(f"{what} returned {shape_text(out)}; accepted: a pair (tau, state)")
            tau, state = out
            check_tau(name, tau, 2, hidden_size, g)


def check_tau(name: str, tau, batch: int, hidden_size: int, like: torch.Tensor) -> None:
    """The core ``name``'s output ``tau`` for ``batch`` episodes is ``(batch, hidden_size)``
    floats of the dtype and on the device of its input ``like``: tried by :func:`check_core`, and
    by the model at every glance of a core that is not built in (a core can keep the contract on
    two episodes and break it on a training batch)."""
    if (
        isinstance(tau, torch.Tensor)
        and tuple(tau.shape) == (batch, hidden_size)
        and tau.dtype == like.dtype
        and tau.device == like.device
    ):
        return
    got = shape_text(tau)
    if isinstance(tau, torch.Tensor):
        got += f" of {tau.dtype} on {tau.device}"
    raise HamError(
        f"core {name!r} of {_file_of(CORES[name])!r} gave tau {got} for {batch} episodes; "
        f"accepted: ({batch}, {hidden_size}) of {like.dtype} on {like.device} (its input's), "
        "hidden_size floats per episode"
    )


def check_poses(name: str, q, batch: int, dims: int, like: torch.Tensor) -> None:
    """The poses ``q`` the policy ``name`` chose for ``batch`` episodes are ``(batch, dims)`` in
    ``[-1, 1]``, of the dtype and on the device of ``like`` (the model's), and carry no gradient
    (the policy learns through ``log_prob``): tried by :func:`check_policy`, and by the model at
    every glance of a policy that is not built in."""
    accepted = f"poses ({batch}, {dims}) in [-1, 1]"
    if not (isinstance(q, torch.Tensor) and tuple(q.shape) == (batch, dims)):
        got = f"{shape_text(q)} for {batch} episodes"
    elif q.dtype != like.dtype or q.device != like.device:
        got = f"poses of {q.dtype} on {q.device}"
        accepted += f" of {like.dtype} on {like.device} (the model's)"
    elif q.requires_grad:
        got = "poses that require grad"
        accepted += " without a gradient (detach them: the policy learns through log_prob)"
    elif not bool(((q >= -1) & (q <= 1)).all()):
        got = f"{q.tolist() if q.numel() <= 8 else 'values'} outside [-1, 1]"
    else:
        return
    raise HamError(
        f"policy {name!r} of {_file_of(POLICIES[name])!r} sampled {got}; accepted: {accepted}"
    )


def check_policy(name: str, policy, hidden_size: int, dims: int) -> None:
    """A location policy that is not built in keeps the contract of
    :class:`ham.model.policy.LocationDistribution`: from ``tau`` of two episodes, a distribution
    whose ``sample`` gives poses ``(2, dims)`` in ``[-1, 1]``, ``log_prob`` and ``entropy`` one
    value per episode, ``mode`` None or poses, and ``stack`` of two glances ``(2, 2)``. Tried on
    a copy under a forked random state, as :func:`check_core`."""
    if name in _BUILTIN["policy"]:
        return
    file = _file_of(POLICIES[name])
    label = f"policy {name!r} of"  # recorded_file.call adds the file
    what = f"{label} {file!r}"

    def need(ok: bool, got, accepted: str) -> None:
        if not ok:
            raise HamError(f"{what} gave {got}; accepted: {accepted}")

    def floats(v: torch.Tensor, what: str) -> None:  # real numbers beside tau (the loss's)
        need(v.is_floating_point() and v.device == tau.device, f"{what} of {v.dtype} on "
             f"{v.device}", f"floats on {tau.device}")  # fmt: skip

    # with autograd on (a copy's graph, dropped after): a trainable distribution's log_prob must
    # carry the gradient that trains the policy
    with torch.random.fork_rng(devices=[]):
        trial = copy.deepcopy(policy)
        tau, position = torch.zeros(2, hidden_size, requires_grad=True), torch.zeros(2, dims)
        d = recorded_file.call(label, file, trial.distribution_at, tau, 1, position)
        need(isinstance(d, LocationDistribution), shape_text(d),
             "a ham.model.policy.LocationDistribution")  # fmt: skip
        q = recorded_file.call(label, file, d.sample, torch.Generator().manual_seed(0))
        check_poses(name, q, 2, dims, tau)
        poses = f"poses (2, {dims}) in [-1, 1]"
        for method, arg in (("log_prob", (q,)), ("entropy", ())):
            v = recorded_file.call(label, file, getattr(d, method), *arg)
            need(isinstance(v, torch.Tensor) and tuple(v.shape) == (2,),
                 f"{method} {shape_text(v)}", "(2,), one value per episode")  # fmt: skip
            floats(v, method)
            if method == "log_prob" and d.trainable:
                need(v.grad_fn is not None, "a log_prob without a gradient", "a log_prob of "
                     "the distribution's parameters (REINFORCE trains the policy through it), "
                     "or trainable = False")  # fmt: skip
        m = recorded_file.call(label, file, d.mode)
        need(m is None or (isinstance(m, torch.Tensor) and tuple(m.shape) == (2, dims)),
             f"mode {shape_text(m)}", f"None or {poses}")  # fmt: skip
        both = recorded_file.call(label, file, type(d).stack, [d, d])
        v = recorded_file.call(label, file, both.log_prob, torch.stack([q, q]))
        need(isinstance(v, torch.Tensor) and tuple(v.shape) == (2, 2),
             f"log_prob {shape_text(v)} of 2 stacked glances", "(2, 2)")  # fmt: skip
        floats(v, "log_prob of 2 stacked glances")
