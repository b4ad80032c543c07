"""A sweep of odd values over the grid file format: ``python -m tests.fuzz_grid [--accepted]``.

A rich grid (every top-level key, a label axis and a value axis, a cell with its own seeds and
world, an evaluation) is the base; each of its keys, at every depth, and an unknown key at three
places, is given each odd value of ``ODD`` in turn, one at a time. Each grid is read as a grid
file's data is (``Grid.from_dict``), then expanded into its runs (``jobs``) and written back
(``to_dict``): nothing trains, nothing is written. A value is flagged when

* an exception other than :class:`ham.errors.HamError` escapes (a traceback in the CLI),
* its HamError's message has more than one line.

``--accepted`` also lists the values taken (most are meaningful: a name of ``'abc'``; the
sweep of 2026-12-03 found ``steps = {}`` among them, an empty table that set nothing). The exit
code is the number of flagged values.
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
import tempfile
import traceback

#: a grid that uses every part of the format (its cell's own world makes a table of its own)
BASE: dict = {
    "name": "g",
    "description": "d",
    "seeds": 2,
    "key": "{variant}-g{model.glances}",
    "evaluate": [{"policy": "sample", "batches": 20, "seed": 1}],
    "table": {"grid": 21},
    "base": {"steps": 10, "eval_every": 5, "eval_batches": 2, "model": {"combiner": "concat2"}},
    "axes": {
        "variant": [{"name": "full"}, {"name": "rloc", "model.policy": "random"}],
        "model.glances": [2, 3],
    },
    "cells": [
        {
            "name": "extra",
            "seeds": [5],
            "model.glances": 4,
            "world": {"pose": {"phi_max": 0.5}, "sensor": {"taxels": 8}},
        }
    ],
    "world": {"objects": "paper", "glance": {"force_threshold": 2.0}},
}
#: odd values given to every key in turn (a grid file may be JSON: any JSON value can arrive)
ODD: list = [math.nan, math.inf, -1, 0, 1.5, "abc", "", None, True, [], {}, [1, "a"], {"x": 1},
             10**30, 1e300, -0.0]  # fmt: skip
#: keys no grid knows, at the top, in the overrides and among the axes
UNKNOWN: list[tuple] = [("unknown",), ("base", "unknown"), ("axes", "model.unknown")]


def places(d, prefix: tuple = ()):
    """Every key path of ``d``, at every depth (list items by index)."""
    for k, v in d.items():
        yield (*prefix, k)
        if isinstance(v, dict):
            yield from places(v, (*prefix, k))
        if isinstance(v, list):
            for i, x in enumerate(v):
                yield (*prefix, k, i)
                if isinstance(x, dict):
                    yield from places(x, (*prefix, k, i))


def with_value(path: tuple, value) -> dict:
    """:data:`BASE` with ``path`` set to ``value``."""
    d = copy.deepcopy(BASE)
    node = d
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return d


def sweep(show_accepted: bool = False) -> tuple[int, list[str]]:
    """Try every place with every value; returns the call count and the flags."""
    from ham.errors import HamError
    from ham.experiments.grid import Grid

    root = tempfile.mkdtemp(prefix="ham-fuzz-grid-")  # table_paths names files; none is made
    calls, flags = 0, []
    for path in [*places(BASE), *UNKNOWN]:
        for value in ODD:
            calls += 1
            where = f"{'.'.join(map(str, path))} = {value!r}"
            try:
                grid = Grid.from_dict(with_value(path, value))
                grid.jobs(grid.table_paths(root))
                grid.to_dict()
            except HamError as exc:
                if "\n" in str(exc):
                    flags.append(f"FLAG {where}: a message of several lines: {exc}")
                continue
            except Exception as exc:  # noqa: BLE001 - what the sweep looks for
                at = traceback.extract_tb(exc.__traceback__)[-1]
                flags.append(
                    f"FLAG {where}: {type(exc).__name__}: {exc} ({at.filename}:{at.lineno})"
                )
                continue
            if show_accepted:
                print(f"accepted {where}")
    return calls, flags


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--accepted", action="store_true", help="also list the values taken")
    args = parser.parse_args(argv)
    calls, flags = sweep(args.accepted)
    for f in flags:
        print(f)
    print(f"{calls} calls: {len(flags)} flagged")
    return min(len(flags), 125)


if __name__ == "__main__":
    sys.exit(main())
