"""Glance tables built once and kept: a cache keyed by a hash of the world and the grid.

A slow world (MuJoCo, e.g. the ``paper-gazebo`` preset: minutes per 201 x 201 table) is built the
first time a command needs its table and read from the cache afterwards. The file name holds the
key, ``table_<grid>_<hash>.h5``, where the hash covers the world's full config, the grid and the
ham version (a new version may glance differently). The build writes ``.partial`` and renames it
(atomic, resumable: :func:`ham.world.table.build_table`); a lock file keeps two processes from
building the same table at once.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from ham.errors import HamError
from ham.world.config import WorldConfig

#: Environment variable naming the cache folder (default ``~/.cache/ham``).
CACHE_ENV = "HAM_CACHE_DIR"


def cache_dir(path: str | os.PathLike | None = None) -> Path:
    """``path``, else ``$HAM_CACHE_DIR``, else ``~/.cache/ham``."""
    if path is None:
        path = os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "ham"
    if not str(path).strip():  # Path("") would be the working folder
        raise HamError(f"cache dir {str(path)!r}; accepted: a folder path")
    p = Path(path).expanduser()
    if p.exists() and not p.is_dir():
        raise HamError(f"cache dir {str(p)!r} is a file; accepted: a folder")
    return p


def table_key(world: WorldConfig, grid: int) -> str:
    """16 hex digits of the SHA-256 of the world's config, the grid and the ham version."""
    import ham

    text = json.dumps(
        {"world": world.to_dict(), "grid": grid, "ham": ham.__version__},
        sort_keys=True,
        default=str,
    )
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def cached_table_path(
    world: WorldConfig, grid: int, directory: str | os.PathLike | None = None
) -> Path:
    """Where the cache keeps ``world``'s ``grid x grid`` table (it may not exist yet)."""
    return cache_dir(directory) / f"table_{grid}_{table_key(world, grid)}.h5"


def cached_table(
    world: WorldConfig,
    grid: int,
    directory: str | os.PathLike | None = None,
    *,
    progress: bool = True,
    command: str | None = None,
) -> Path:
    """The cached table of ``world`` at ``grid``, built now (once) when missing."""
    import fcntl

    from ham.world.table import build_table

    path = cached_table_path(world, grid, directory)
    if path.exists():
        return path
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise HamError(
            f"cache folder '{path.parent}' cannot be made ({exc.strerror}); accepted: a folder "
            "this user can create and write (--cache-dir or $HAM_CACHE_DIR)"
        ) from None
    with open(path.with_name(path.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # another process may be building it: wait for it
        if not path.exists():
            build_table(world, grid, path, progress=progress, command=command)
    return path
