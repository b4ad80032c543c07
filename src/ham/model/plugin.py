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

from pathlib import Path

from ham.model.core import CORES
from ham.model.policy import POLICIES
from ham.world import recorded_file, registering

SUFFIXES: tuple[str, ...] = (".py",)
#: What a plugin may register, by label: cores and policies here; an upper layer adds its own
#: registry when it is imported (:func:`add_registry`; ``ham.learn.learners``: ``learner``), so
#: that imports point down the layers.
REGISTRIES: dict[str, dict] = {"core": CORES, "policy": POLICIES}
#: label -> the names a registry holds before any plugin (its built-in ones)
_BUILTIN: dict[str, tuple[str, ...]] = {"core": tuple(CORES), "policy": tuple(POLICIES)}
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
