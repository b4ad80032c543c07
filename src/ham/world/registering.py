"""Running a user's file that registers things (a plugin's cores and policies, a simulator
file's simulators): what it added, and nothing left behind when it fails.

Objects files register objects themselves (:func:`ham.world.objects.load_objects`); any other
file that registers objects is refused, since only an objects file is recorded where objects are
looked up (a world).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from ham.errors import HamError
from ham.world import objects as _objects
from ham.world import recorded_file


def run_registering(
    what: str,
    record: dict,
    module: str,
    registries: Mapping[str, dict],
    nothing: str,
    hint: str,
    builtin: Mapping[str, Iterable[str]] | None = None,
) -> dict[str, list[str]]:
    """Run the Python of the (checked) ``record``; the names it added to each of ``registries``
    (a label -> a dict registry, e.g. ``{"core": CORES}``).

    ``registries`` may be a live mapping that grows while the file runs (an upper layer's
    registry joins it when the file imports that layer); such a registry's names other than its
    ``builtin`` ones count as added. A file that fails, adds nothing (``nothing``: what it should
    add; ``hint``: how) or registers objects (they belong in an objects file, which a world
    records) leaves every registry, the objects' too, as it was.
    """
    name = record["name"]
    builtin = builtin or {}
    before = {label: set(registry) for label, registry in registries.items()}

    def new(label: str, registry: dict) -> list[str]:
        return [n for n in registry if n not in before.get(label, set(builtin.get(label, ())))]

    objs = set(_objects.names())
    try:
        recorded_file.run_python(what, name, record["source"], module)
        added_objects = [n for n in _objects.names() if n not in objs]
        if added_objects:
            raise HamError(
                f"{what} {name!r} registers objects {added_objects}; accepted: objects in an "
                "objects file (--objects-file), which tables and runs record"
            )
        added = {label: new(label, registry) for label, registry in registries.items()}
        if not any(added.values()):
            raise HamError(f"{what} {name!r} registers {nothing}; accepted: {hint}")
    except BaseException:
        for label, registry in registries.items():
            for n in new(label, registry):
                del registry[n]
        _objects.unregister_since(objs)
        raise
    return added
