"""Plugins: the user's own cores and location policies, from a Python file (``--plugin FILE.py``).

A plugin is a self-contained Python file that registers cores (:func:`ham.model.core.register_core`)
and location policies (:func:`ham.model.policy.register_policy`); ``ham train --plugin FILE.py
--core NAME`` / ``--policy NAME`` then trains with them, and nothing in the package is edited. A
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
    got = registering.run_registering(
        "plugin", record, "ham_plugin", {"core": CORES, "policy": POLICIES},
        "no core or location policy",
        "a file that calls ham.model.core.register_core or ham.model.policy.register_policy",
    )  # fmt: skip
    added = [f"{label} {n}" for label, names in got.items() for n in names]
    _LOADED[sha] = tuple(added)
    return list(added)
