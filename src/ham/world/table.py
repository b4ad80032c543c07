"""Glance tables: the paper's pre-recorded data set (section "Creation of the dataset").

For every object, glances on a ``grid x grid`` lattice of normalized poses
``q_x, q_phi in {-1, -1 + 2/(grid-1), ..., 1}`` (the paper: 201 x 201, steps 0.01 in x and
0.01 pi in phi). A pose the agent asks for is answered by the closest grid point.

File layout (HDF5, self-describing)::

    /                       attrs: format, format_version, grid, q_range, objects (JSON),
                                   world (JSON WorldConfig), sensor (JSON SensorConfig, also in
                                   world), geometry (JSON outlines), simulator description (JSON),
                                   ham_version, command, created, checksum (pressures),
                                   record_checksum (every other attribute and dataset)
    /objects/<name>/pressure  (grid, grid, N, N) float32, raw Pa; axis 0 = q_x index, 1 = q_phi;
                              N = the sensor's taxels (16)
    /objects/<name>/force     (grid, grid) float32, N (NaN where unknown, e.g. imported data)
    /objects/<name>/z         (grid, grid) float32, m
    /objects/<name>/contact   (grid, grid) bool

Tables over any pose grid (format version 2, beyond the paper): for a world whose pose dims
are not the paper's ``(x, phi)`` (``WorldConfig.pose_dims``, e.g. ``x, y, phi, phi_y``) or a
grid that differs per axis, the poses are the points of a ``g_1 x .. x g_k`` lattice, and each
object's data are stored flat over the lattice, row-major (last pose dim fastest), in chunked,
compressed datasets::

    /                       attrs: as above, plus pose_dims (JSON list), grid_shape (JSON list),
                                   compression; grid = g_1
    /objects/<name>/pressure  (P, N, N) float32, P = g_1 * .. * g_k; chunks of whole images
    /objects/<name>/force, height  (P,) float32; contact (P,) bool

``height`` is the contact height ``h`` (m), the face centre's final height; version-1 tables keep
it as ``z``. A 2-D ``(x, phi)`` square grid is written in version 1 exactly as before (the
``paper`` table is bit-identical). Loading reads a table into memory; a table larger than
``max_memory`` bytes (or ``lookup="stream"``) stays on disk: an uncompressed one
(``compression="none"``) is memory-mapped, a compressed one is read per batch (the images a
batch asks for, one sorted read per object). Online glances are the default for 4-D poses.

Files are written atomically: a build writes ``FILE.partial`` (resumable: finished q_x rows are
marked in ``/progress``) and renames it to ``FILE`` only when complete and checksummed.

Reading checks a table before use (:meth:`GlanceTable.load`, :func:`verify_table`, ``ham table
verify``): its attributes and dataset shapes, at least one object, finite non-negative
pressures, the sha256 checksum of the pressures, and the record checksum of everything else
(attributes, force, z or height, contact; tables from before it have none). On the paper's 201 x
201 table (165 MB) the checksums add about 0.25 s to a 0.13 s load (warm cache, one core), so
loads keep them on.
"""

from __future__ import annotations

import hashlib
import json
import os
import shlex
import sys
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
import torch
from tqdm.auto import tqdm

import ham
from ham.errors import HamError, checked_arguments
from ham.world.config import WorldConfig, make_simulator
from ham.world.files import atomic_write, check_output
from ham.world.glance import check_pose_dims
from ham.world.objects import load_objects
from ham.world.poses import result_height, simulate, world_pose_dims
from ham.world.sensor import MAX_PRESSURE, SensorConfig

FORMAT = "ham-glance-table"
FORMAT_VERSION = 1
#: Tables over any pose grid (module doc); version 1 is the paper's square (x, phi) grid.
FORMAT_VERSION_GRID = 2
FORMAT_VERSIONS = (FORMAT_VERSION, FORMAT_VERSION_GRID)
PAPER_POSE_DIMS = ("x", "phi")
#: Compressions of version-2 tables: gzip (default, portable), lzf (faster), none (memory-mappable).
COMPRESSIONS: tuple[str, ...] = ("gzip", "lzf", "none")
#: Tables above this many pressure bytes are not read into memory by default (``lookup="auto"``).
MAX_MEMORY = 2 * 1024**3
LOOKUPS: tuple[str, ...] = ("auto", "memory", "stream")
#: Largest number of poses in a version-2 table (a 4-D grid of 51^4 is 6.8 M).
MAX_POSES = 50_000_000
AUTHORS_OBJECTS = ("box", "ramp_up", "convex", "ramp_down")
#: The authors' data set is the paper's pad: 16 x 16 taxels, flattened to 256 values.
AUTHORS_TAXELS = 16


def grid_values(grid: int) -> np.ndarray:
    """The normalized pose values of a grid axis: ``grid`` points from -1 to 1."""
    return np.linspace(-1.0, 1.0, grid)


def nearest_index(q: torch.Tensor, grid: int) -> torch.Tensor:
    """Index of the closest grid point to ``q`` in [-1, 1] (exact on grid points)."""
    return torch.round((q + 1.0) * (0.5 * (grid - 1))).long().clamp_(0, grid - 1)


#: The largest grid of a glance table: 2001 x 2001 poses (4 million glances an object).
MAX_GRID = 2001


def _check_grid(grid: int) -> None:
    if not (isinstance(grid, int) and not isinstance(grid, bool) and 2 <= grid <= MAX_GRID):
        raise HamError(f"grid = {grid!r}; accepted: an integer 2..{MAX_GRID} (the paper uses 201)")


def grid_shape_for(grid, pose_dims: tuple[str, ...]) -> tuple[int, ...]:
    """Points per pose axis: ``grid`` an integer (every axis) or one integer per pose dim (a
    sequence, or a comma-separated string such as ``"21,21,9,9"``)."""
    if isinstance(grid, str):
        try:
            grid = [int(g) for g in grid.split(",")]
        except ValueError:
            raise HamError(
                f"grid = {grid!r}; accepted: an integer or one per pose dim, e.g. 21,21,9,9"
            ) from None
        if len(grid) == 1:
            grid = grid[0]
    if isinstance(grid, (list, tuple)):
        if len(grid) != len(pose_dims):
            raise HamError(
                f"grid = {','.join(map(str, grid))}: {len(grid)} axes for the {len(pose_dims)} "
                f"pose dims {','.join(pose_dims)}; accepted: one integer, or one per pose dim"
            )
        for g in grid:
            _check_grid(g)
        shape = tuple(int(g) for g in grid)
    else:
        _check_grid(grid)
        shape = (int(grid),) * len(pose_dims)
    poses = int(np.prod(shape))
    if poses > MAX_POSES:
        raise HamError(
            f"grid {'x'.join(map(str, shape))} has {poses:,} poses per object; accepted: at most "
            f"{MAX_POSES:,} (use online glances for finer 4-D poses)"
        )
    return shape


def is_paper_layout(pose_dims: tuple[str, ...], shape: tuple[int, ...]) -> bool:
    """A square ``(x, phi)`` grid: written in the paper's format version 1."""
    return tuple(pose_dims) == PAPER_POSE_DIMS and shape[0] == shape[1]


def _python_command(call: str) -> str:
    """The command of a table written through the Python API: the program and the call."""
    argv = [a for a in sys.argv if a]
    return f"python {shlex.join(argv)}: {call}" if argv else f"python: {call}"


def bad_pressure(a: np.ndarray) -> tuple[int, ...] | None:
    """The index of the first value of ``a`` outside ``[0, MAX_PRESSURE]`` Pa (NaN included),
    or ``None`` when every pressure is one."""
    # two reductions (NaN propagates into both, and fails either comparison; so does an inf)
    # instead of a mask over 16 M values, as the simulator-file check does on its tensors
    lo, hi = a.min(initial=0.0), a.max(initial=0.0)
    if lo >= 0 and hi <= MAX_PRESSURE:
        return None
    return tuple(int(k) for k in np.argwhere(~((a >= 0) & (a <= MAX_PRESSURE)))[0])


def _check_pressure(path: str, name: str, a: np.ndarray) -> None:
    """Pressures in ``[0, MAX_PRESSURE]`` Pa, or a :class:`HamError` naming the first bad value."""
    i = bad_pressure(a)
    if i is None:
        return
    raise HamError(
        f"glance table {path!r} is corrupt: objects/{name}/pressure holds {float(a[i])} at index "
        f"{i}; accepted: pressures in [0, {MAX_PRESSURE:g}] Pa"
    )


def _checksum(f: h5py.File, names: list[str], rows: int = 65536) -> str:
    """sha256 of every object's pressure in order, read ``rows`` images at a time (the same
    digest as over whole arrays: sha256 streams)."""
    h = hashlib.sha256()
    for name in names:
        ds = f[f"objects/{name}/pressure"]
        for i in range(0, ds.shape[0], rows):
            h.update(np.ascontiguousarray(ds[i : i + rows]).tobytes())
    return h.hexdigest()


#: attributes the record checksum leaves out: the checksums themselves
_UNRECORDED = ("checksum", "record_checksum")


def _record_checksum(f: h5py.File, names: list[str]) -> str:
    """sha256 of what the pressure checksum leaves out: every root attribute (the world, its
    objects and geometry, the grid, the command) and every object's other datasets (force, z or
    height, contact), so a flipped bit anywhere in a table is found, not read as another world."""
    h = hashlib.sha256()
    for key in sorted(k for k in f.attrs if k not in _UNRECORDED):
        v = f.attrs[key]
        h.update(repr((key, v.tolist() if hasattr(v, "tolist") else v)).encode())
    for name in names:
        g = f[f"objects/{name}"]
        for key in sorted(k for k in g if k != "pressure"):
            h.update(f"{name}/{key}".encode())
            h.update(np.ascontiguousarray(g[key][...]).tobytes())
    return h.hexdigest()


def _check_record(f: h5py.File, info: TableInfo, path: str) -> None:
    """The record checksum of a table that has one (tables built before it have none)."""
    recorded = info.record_checksum  # as _read_info read it
    if recorded is None:
        return
    try:
        got = _record_checksum(f, info.objects)
    except (OSError, KeyError) as exc:
        raise HamError(f"cannot read glance table {path!r}: {exc}") from None
    if got != recorded:
        raise HamError(
            f"glance table {path!r} is corrupt: its attributes or force/height/contact data do "
            f"not match their checksum (recorded {recorded[:12]}..., data {got[:12]}...); "
            "accepted: the table as built (rebuild it with `ham table build`)"
        )


# --------------------------------------------------------------------------- build
@checked_arguments
def build_table(
    world: WorldConfig,
    grid: int | tuple[int, ...] | str,
    out: str | os.PathLike,
    *,
    batch: int | None = None,
    progress: bool = True,
    command: str | None = None,
    compression: str | None = None,
    **sim_kwargs,
) -> Path:
    """Record ``grid x grid`` glances per object of ``world`` into the HDF5 file ``out``; over
    the world's pose dims (``grid``: points per axis, one integer or one per dim) in format
    version 2 when they are not the paper's square ``(x, phi)`` grid (module doc).

    Resumes from ``out.partial`` when one exists for the same world and grid. ``command`` is
    recorded in the file (the CLI passes its argv; default: the Python program and this call).
    The world, and so any objects file it was built from (name, sha256, text), is recorded too.
    ``compression`` (version 2 only): gzip (``None``: the default), lzf or none (a
    memory-mappable file); the paper's table (version 1) is stored uncompressed.
    """
    # A build that fails (e.g. a simulator of the user's that returns bad glances) leaves no
    # partial file of its own: a rerun would fail the same way, and a fixed simulator is another
    # world. An interrupted build keeps it, to resume.
    partial = Path(os.fspath(out) + ".partial")
    fresh = not partial.exists()
    try:
        return _build_table(world, grid, out, batch, progress, command, compression, sim_kwargs)
    except HamError:
        if fresh:
            partial.unlink(missing_ok=True)
        raise


def _build_table(world, grid, out, batch, progress, command, compression, sim_kwargs) -> Path:
    if batch is not None and batch < 1:
        raise HamError(f"batch = {batch!r}; accepted: an integer >= 1 (poses a chunk) or None")
    dims = world_pose_dims(world)
    shape = grid_shape_for(grid, dims)
    if compression is not None and compression not in COMPRESSIONS:
        raise HamError(f"compression = {compression!r}; accepted: {', '.join(COMPRESSIONS)}")
    if not is_paper_layout(dims, shape):
        compression = compression or "gzip"
        return _build_grid_table(
            world, dims, shape, out, batch, progress, command, compression, sim_kwargs
        )
    if compression is not None:  # said, not silently ignored
        raise HamError(
            f"compression = {compression!r} for the paper's (x, phi) table, which is stored "
            "uncompressed; accepted: a compression for a table over other pose dims (format 2)"
        )
    grid = shape[0]
    out, partial, objs, names, world_json, sim = _start_build(world, out, sim_kwargs)
    n_tax = world.sensor.taxels
    q = grid_values(grid)
    # Rows of q_x per simulator call: the fast model takes whole objects, slow engines less.
    batch = batch or (grid * grid if sim.name == "fast" else 16 * grid)
    rows_per_call = max(1, batch // grid)

    f, mode = _open_partial(partial)
    with f:
        if mode == "a" and (
            f.attrs.get("world") != world_json or int(f.attrs.get("grid", -1)) != grid
        ):
            raise HamError(
                f"{partial} is a partial build of another world or grid; delete it to start over"
            )
        if mode == "w":
            f.attrs.update(
                format=FORMAT,
                format_version=FORMAT_VERSION,
                grid=grid,
                **_world_attrs(world, world_json, objs, sim),
            )
            f.create_dataset("progress", data=np.zeros((len(objs), grid), bool))
            for name in names:
                g = f.create_group(f"objects/{name}")
                g.create_dataset("pressure", (grid, grid, n_tax, n_tax), np.float32)
                g.create_dataset("force", (grid, grid), np.float32)
                g.create_dataset("z", (grid, grid), np.float32)
                g.create_dataset("contact", (grid, grid), bool)
        done = f["progress"][...]
        todo = int((~done).sum()) * grid  # a partly done block is redone whole
        with tqdm(
            total=len(objs) * grid * grid,
            initial=len(objs) * grid * grid - todo,
            desc=f"glance table ({sim.name})",
            unit="glance",
            disable=not progress,
            file=sys.stderr,
        ) as bar:
            for oi, name in enumerate(names):
                g = f[f"objects/{name}"]
                for r0 in range(0, grid, rows_per_call):
                    sl = slice(r0, min(r0 + rows_per_call, grid))
                    if done[oi, sl].all():
                        continue
                    n = sl.stop - sl.start
                    r = sim.glance(np.full(n * grid, oi), np.repeat(q[sl], grid), np.tile(q, n))
                    g["pressure"][sl] = r.pressure.cpu().numpy().reshape(n, grid, n_tax, n_tax)
                    g["force"][sl] = r.force.cpu().numpy().reshape(n, grid)
                    g["z"][sl] = r.z.cpu().numpy().reshape(n, grid)
                    g["contact"][sl] = r.contact.cpu().numpy().reshape(n, grid)
                    f["progress"][oi, sl] = True  # only after the data: a crash redoes the block
                    f.flush()
                    bar.update(int((~done[oi, sl]).sum()) * grid)
        _finish_build(f, names, command, grid, out)
    os.replace(partial, out)
    return out


def grid_poses(shape: tuple[int, ...], start: int, stop: int) -> np.ndarray:
    """Poses ``start .. stop - 1`` of the row-major lattice ``shape`` as ``(n, k)`` values."""
    idx = np.unravel_index(np.arange(start, stop), shape)
    return np.stack([grid_values(g)[i] for g, i in zip(shape, idx, strict=True)], 1)


def _build_grid_table(world, dims, shape, out, batch, progress, command, compression, sim_kwargs):
    """:func:`build_table` in format version 2: any pose dims, any grid per axis."""
    out, partial, objs, names, world_json, sim = _start_build(world, out, sim_kwargs)
    n_tax = world.sensor.taxels
    poses = int(np.prod(shape))
    batch = max(1, min(poses, batch or (65536 if sim.name == "fast" else 4096)))
    blocks = -(-poses // batch)
    chunk_rows = max(1, min(poses, 262144 // (4 * n_tax * n_tax)))  # ~256 KB chunks
    comp = None if compression == "none" else compression
    opts = dict(compression=comp, chunks=True) if comp else {}
    spec = json.dumps(
        {"grid_shape": list(shape), "pose_dims": list(dims), "compression": compression}
    )
    f, mode = _open_partial(partial)
    with f:
        if mode == "a" and (f.attrs.get("world") != world_json or f.attrs.get("build") != spec):
            raise HamError(
                f"{partial} is a partial build of another world or grid; delete it to start over"
            )
        if mode == "w":
            f.attrs.update(
                format=FORMAT,
                format_version=FORMAT_VERSION_GRID,
                grid=shape[0],
                grid_shape=json.dumps(list(shape)),
                pose_dims=json.dumps(list(dims)),
                compression=compression,
                build=spec,
                **_world_attrs(world, world_json, objs, sim),
            )
            f.create_dataset("progress", data=np.zeros((len(objs), blocks), bool))
            for name in names:
                g = f.create_group(f"objects/{name}")
                if comp:
                    g.create_dataset("pressure", (poses, n_tax, n_tax), np.float32,
                                     chunks=(chunk_rows, n_tax, n_tax), compression=comp)  # fmt: skip
                else:
                    g.create_dataset("pressure", (poses, n_tax, n_tax), np.float32)
                g.create_dataset("force", (poses,), np.float32, **opts)
                g.create_dataset("height", (poses,), np.float32, **opts)
                g.create_dataset("contact", (poses,), bool, **opts)
        done = f["progress"][...]
        with tqdm(
            total=len(objs) * poses,
            initial=int(done.sum()) * batch,
            desc=f"glance table ({sim.name}, {'x'.join(map(str, shape))})",
            unit="glance",
            disable=not progress,
            file=sys.stderr,
        ) as bar:
            for oi, name in enumerate(names):
                g = f[f"objects/{name}"]
                for b in range(blocks):
                    if done[oi, b]:
                        continue
                    sl = slice(b * batch, min((b + 1) * batch, poses))
                    q = torch.from_numpy(grid_poses(shape, sl.start, sl.stop))
                    ids = torch.full((len(q),), oi, dtype=torch.long)
                    r = simulate(sim, ids, q, dims)
                    g["pressure"][sl] = r.pressure.cpu().numpy()
                    g["force"][sl] = r.force.cpu().numpy()
                    g["height"][sl] = result_height(r).cpu().numpy()
                    g["contact"][sl] = r.contact.cpu().numpy()
                    f["progress"][oi, b] = True  # only after the data: a crash redoes the block
                    f.flush()
                    bar.update(sl.stop - sl.start)
        _finish_build(f, names, command, list(shape), out)
    os.replace(partial, out)
    return out


def _start_build(world: WorldConfig, out, sim_kwargs: dict):
    """What both table formats' builds start from: the checked output path and its ``.partial``
    twin, the world's objects and names, its JSON and its simulator."""
    out = check_output(out, (".h5", ".hdf5"), what="glance table")
    try:  # first: a misspelled option leaves no folder
        sim = make_simulator(world, **sim_kwargs)
    except TypeError as exc:
        if not (sim_kwargs and "unexpected keyword argument" in str(exc)):
            raise
        raise HamError(
            f"build_table: {exc}; accepted: the options of simulator {world.simulator!r}"
        ) from None
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".partial")
    objs = world.resolve_objects()
    names = [o.name for o in objs]
    world_json = json.dumps(world.to_dict(), sort_keys=True)
    return out, partial, objs, names, world_json, sim


def _open_partial(partial: Path):
    """The partial build file, opened to resume (``a``) when it exists, else new (``w``)."""
    mode = "a" if partial.exists() else "w"
    try:
        return h5py.File(partial, mode), mode
    except OSError as exc:
        if "unable to lock file" in str(exc):  # HDF5's own lock: another build holds the file
            out = partial.with_name(partial.name.removesuffix(".partial"))
            raise HamError(
                f"glance table '{out}' is being built by another ham process; accepted: an --out "
                "no running ham writes (wait for that one to end, or stop it)"
            ) from None
        raise HamError(f"cannot write glance table {partial}: {exc}") from None


def _world_attrs(world: WorldConfig, world_json: str, objs: list, sim) -> dict:
    """The attributes that describe a table's world, in both formats (in this order)."""
    return dict(
        q_range=json.dumps([-1.0, 1.0]),
        objects=json.dumps([o.name for o in objs]),
        world=world_json,
        sensor=json.dumps(world.sensor.to_dict(), sort_keys=True),
        geometry=json.dumps({o.name: o.outline().tolist() for o in objs}),
        simulator=json.dumps(sim.describe(), sort_keys=True, default=str),
        ham_version=ham.__version__,
    )


def _finish_build(f: h5py.File, names: list[str], command: str | None, grid, out: Path) -> None:
    """Record the command (``build_table(grid=grid, out=out)`` when none is given), the time and
    the checksum; drop the build's progress marks."""
    f.attrs["command"] = command or _python_command(
        f"ham.world.table.build_table(grid={grid}, out={str(out)!r})"
    )
    f.attrs["created"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    f.attrs["checksum"] = _checksum(f, names)
    del f["progress"]
    if "build" in f.attrs:  # a version-2 build's resume key
        del f.attrs["build"]
    f.attrs["record_checksum"] = _record_checksum(f, names)  # last: over every attribute


# --------------------------------------------------------------------------- read
@dataclass
class TableInfo:
    path: str
    grid: int
    objects: list[str]
    world: dict
    simulator: dict
    ham_version: str
    command: str
    created: str
    checksum: str
    source: str
    sensor: dict = field(default_factory=dict)
    #: the pose dims of the grid's axes (the paper's ``x, phi``) and the points per axis
    pose_dims: tuple = PAPER_POSE_DIMS
    grid_shape: tuple = ()
    format_version: int = FORMAT_VERSION
    compression: str = "none"
    #: sha256 of the attributes and the force/height/contact data (None: a table from before it)
    record_checksum: str | None = None

    def __post_init__(self) -> None:
        if not self.grid_shape:
            self.grid_shape = (self.grid,) * len(self.pose_dims)

    @property
    def poses(self) -> int:
        """Grid poses per object."""
        return int(np.prod(self.grid_shape))

    @property
    def taxels(self) -> int:
        """Cells per side of the table's images (16)."""
        return int(self.sensor.get("taxels", 16))

    @property
    def pressure_dim(self) -> int:
        """Values in one flattened image, the input size of a model that reads this table."""
        return self.taxels**2

    def to_dict(self) -> dict:
        d = dict(self.__dict__)
        d["pose_dims"], d["grid_shape"] = list(self.pose_dims), list(self.grid_shape)
        return d


def _open(path: str | os.PathLike) -> h5py.File:
    p = Path(path)
    if not p.exists():
        raise HamError(f"glance table {str(p)!r} does not exist")
    if not p.is_file():
        raise HamError(f"glance table {str(p)!r} is not a file; accepted: an HDF5 glance table")
    try:
        return h5py.File(p, "r")
    except OSError as exc:
        raise HamError(
            f"cannot read glance table {str(p)!r}: not a complete HDF5 file ({exc})"
        ) from None


def _read_info(f: h5py.File, path: str) -> TableInfo:
    a = f.attrs
    if a.get("format") != FORMAT:
        raise HamError(f"{path!r} is not a ham glance table (format attribute {a.get('format')!r})")
    version = int(a.get("format_version", -1))
    if version not in FORMAT_VERSIONS:
        raise HamError(
            f"{path!r} has table format version {a.get('format_version')}; accepted: "
            f"{', '.join(map(str, FORMAT_VERSIONS))}"
        )
    try:
        grid = int(a["grid"])
        dims, shape = PAPER_POSE_DIMS, (grid, grid)
        if version == FORMAT_VERSION_GRID:
            dims = tuple(json.loads(a["pose_dims"]))
            shape = tuple(int(g) for g in json.loads(a["grid_shape"]))
        names = json.loads(a["objects"])
        world = json.loads(a["world"])
        simulator = json.loads(a.get("simulator", "{}"))
        checksum = str(a["checksum"])
        # The sensor: its own attribute, else the world's (tables from before it), else the paper's.
        sensor = world.get("sensor", {})
        if "sensor" in a:
            sensor = json.loads(a["sensor"])
            if "sensor" in world and world["sensor"] != sensor:
                raise HamError(
                    f"{path!r}: its sensor attribute {sensor} and its world's sensor "
                    f"{world['sensor']} differ"
                )
        sensor = SensorConfig(**sensor).to_dict()
    except (KeyError, ValueError, TypeError) as exc:
        raise HamError(f"{path!r}: glance table attributes are incomplete ({exc})") from None
    if not (isinstance(names, list) and names and all(isinstance(n, str) for n in names)):
        raise HamError(
            f"glance table {path!r} lists objects {names!r}; accepted: one or more object names"
        )
    if len(set(names)) != len(names):
        raise HamError(f"glance table {path!r} lists an object twice: {names}")
    if not (len(shape) == len(dims) >= 1 and all(2 <= g <= MAX_GRID for g in shape)):
        raise HamError(
            f"glance table {path!r} has grid {'x'.join(map(str, shape))} over pose dims "
            f"{','.join(dims)}; accepted: 2..{MAX_GRID} points on each pose axis"
        )
    n = sensor["taxels"]
    if version == FORMAT_VERSION:
        expected = (
            ("pressure", (grid, grid, n, n)),
            ("force", (grid, grid)),
            ("z", (grid, grid)),
            ("contact", (grid, grid)),
        )
    else:
        poses = int(np.prod(shape))
        expected = (
            ("pressure", (poses, n, n)),
            ("force", (poses,)),
            ("height", (poses,)),
            ("contact", (poses,)),
        )
    for name in names:
        for key, shape_ in expected:
            ds = f.get(f"objects/{name}/{key}")
            if ds is None:
                raise HamError(f"{path!r}: objects/{name}/{key} is missing; a glance table has one")
            if ds.shape != shape_:
                raise HamError(
                    f"{path!r}: objects/{name}/{key} has shape {ds.shape}, expected {shape_}"
                )
    return TableInfo(
        path=str(path),
        grid=grid,
        objects=names,
        world=world,
        simulator=simulator,
        ham_version=str(a.get("ham_version", "?")),
        command=str(a.get("command", "")),
        created=str(a.get("created", "")),
        checksum=checksum,
        record_checksum=str(a["record_checksum"]) if "record_checksum" in a else None,
        source=str(a.get("source", "ham")),
        sensor=sensor,
        pose_dims=tuple(dims),
        grid_shape=tuple(shape),
        format_version=version,
        compression=str(a.get("compression", "none")),
    )


@checked_arguments
def table_info(path: str | os.PathLike) -> TableInfo:
    """The table's self-description, with its structure checked (not its data: see verify_table)."""
    with _open(path) as f:
        return _read_info(f, str(path))


def _read_pressure(f: h5py.File, info: TableInfo, path: str, verify: bool) -> list[np.ndarray]:
    """Every object's pressure, checked finite and non-negative, and the checksum if ``verify``."""
    try:
        arrays = [f[f"objects/{n}/pressure"][...] for n in info.objects]
    except (OSError, KeyError) as exc:
        raise HamError(f"cannot read glance table {path!r}: {exc}") from None
    for name, a in zip(info.objects, arrays, strict=True):
        _check_pressure(path, name, a)
    if verify:
        h = hashlib.sha256()
        for a in arrays:
            h.update(np.ascontiguousarray(a).tobytes())
        if h.hexdigest() != info.checksum:
            raise HamError(
                f"glance table {path!r} is corrupt: its checksum does not match its data "
                f"(recorded {info.checksum[:12]}..., data {h.hexdigest()[:12]}...)"
            )
    return arrays


@checked_arguments
def verify_table(path: str | os.PathLike) -> TableInfo:
    """Check a table completely (``ham table verify``): attributes, shapes, at least one object,
    finite non-negative pressures and the sha256 checksum; a :class:`HamError` names the problem.
    A version-2 table is read in blocks (any size)."""
    with _open(path) as f:
        info = _read_info(f, str(path))
        if info.format_version == FORMAT_VERSION:
            _read_pressure(f, info, str(path), verify=True)
        else:
            _verify_streamed(f, info, str(path))
        _check_record(f, info, str(path))
    return info


def _verify_streamed(f: h5py.File, info: TableInfo, path: str, rows: int = 65536) -> None:
    """:func:`verify_table` of a version-2 table, ``rows`` images at a time."""
    h = hashlib.sha256()
    for name in info.objects:
        ds = f[f"objects/{name}/pressure"]
        for i in range(0, ds.shape[0], rows):
            try:
                a = np.ascontiguousarray(ds[i : i + rows])
            except OSError as exc:
                raise HamError(f"cannot read glance table {path!r}: {exc}") from None
            _check_pressure(path, name, a)
            h.update(a.tobytes())
    if h.hexdigest() != info.checksum:
        raise HamError(
            f"glance table {path!r} is corrupt: its checksum does not match its data "
            f"(recorded {info.checksum[:12]}..., data {h.hexdigest()[:12]}...)"
        )


class GlanceTable:
    """A loaded glance table with vectorized nearest-grid-point lookup (CPU or CUDA).

    ``pressure`` is a ``(n_objects, g_1, .., g_k, N, N)`` float32 tensor of raw pressure (the
    paper: ``(n_objects, grid, grid, N, N)``), ``N`` the recorded sensor's ``taxels`` (16);
    ``height`` the ``(n_objects, g_1, .., g_k)`` contact heights (m). A streamed table (too
    large for memory, :meth:`load`) has ``pressure = None`` and reads its images per batch.
    """

    def __init__(
        self,
        info: TableInfo,
        pressure: torch.Tensor | None,
        extras: dict[str, np.ndarray],
        stream=None,
    ):
        self.info = info
        self.grid = info.grid
        self.grid_shape = tuple(info.grid_shape)
        self.pose_dims = tuple(info.pose_dims)
        self.objects = list(info.objects)
        self.n_objects = len(self.objects)
        self.taxels = info.taxels
        self.pressure_dim = info.pressure_dim
        self.pressure = pressure
        self.extras = extras
        self._stream = stream  # _Stream: the on-disk images of a streamed table
        key = "z" if info.format_version == FORMAT_VERSION else "height"
        device = pressure.device if pressure is not None else torch.device("cpu")
        self.height = torch.from_numpy(
            np.asarray(extras[key], dtype=np.float32).reshape(self.n_objects, *self.grid_shape)
        ).to(device)
        strides, acc = [], 1
        for g in reversed(self.grid_shape):
            strides.append(acc)
            acc *= g
        self._strides = list(reversed(strides))  # row-major pose index
        # every pose dim on one grid (the paper's tables): the index of all dims in one pass
        self._stride_t = (
            torch.tensor(self._strides, device=device) if len(set(self.grid_shape)) == 1 else None
        )

    @property
    def world(self) -> WorldConfig:
        """The world the table was built in (its objects file's objects are registered)."""
        return WorldConfig.from_dict(self.info.world)

    @property
    def device(self) -> torch.device:
        return self.height.device

    @property
    def streamed(self) -> bool:
        """The images stay on disk (memory-mapped or read per batch)."""
        return self._stream is not None

    @property
    def knows_heights(self) -> bool:
        """Whether every glance's contact height is known (glances imported without heights
        leave them NaN: a model or planner that reads heights is refused such a table)."""
        return bool(torch.isfinite(self.height).all())

    @classmethod
    @checked_arguments
    def load(
        cls,
        path: str | os.PathLike,
        *,
        verify: bool = True,
        device: str = "cpu",
        lookup: str = "auto",
        max_memory: int = MAX_MEMORY,
    ) -> GlanceTable:
        """Read ``path``; refuse truncated, corrupt or mismatched files with a clear error.

        Structure, finite non-negative pressures and (with ``verify``, the default) the
        checksum are checked: see the module doc for the cost. Registers the objects of the
        objects file the table was built from (hash verified).

        ``lookup``: ``memory`` reads the images into memory; ``stream`` leaves them on disk
        (memory-mapped when stored uncompressed, else read per batch; CPU only, no checks of
        the data: ``ham table verify`` checks a big table); ``auto`` streams a version-2 table
        whose images exceed ``max_memory`` bytes.
        """
        from ham.world.devices import check_device

        if lookup not in LOOKUPS:
            raise HamError(f"lookup = {lookup!r}; accepted: {', '.join(LOOKUPS)}")
        if max_memory < 0:
            raise HamError(f"max_memory = {max_memory!r}; accepted: a byte count >= 0")
        device = check_device(device)
        with _open(path) as f:
            info = _read_info(f, str(path))
            if info.world.get("objects_file") is not None:
                load_objects(info.world["objects_file"])
            size = len(info.objects) * info.poses * info.pressure_dim * 4
            stream = info.format_version == FORMAT_VERSION_GRID and (
                lookup == "stream" or (lookup == "auto" and size > max_memory)
            )
            if lookup == "stream" and info.format_version == FORMAT_VERSION:
                raise HamError(
                    f"lookup = 'stream' on {str(path)!r}, a version-1 (paper) table; accepted: "
                    "memory or auto for it (streaming is for version-2 grid tables)"
                )
            if stream and str(device) != "cpu":
                raise HamError(
                    f"a streamed glance table ({size / 1024**3:.1f} GiB of images) on {device}; "
                    "accepted: device cpu, or lookup='memory' if it fits"
                )
            arrays = None if stream else _read_pressure(f, info, str(path), verify)
            keys = ("force", "z", "contact") if info.format_version == FORMAT_VERSION else (
                "force", "height", "contact")  # fmt: skip
            try:
                extras = {key: np.stack([f[f"objects/{n}/{key}"][...] for n in info.objects])
                          for key in keys}  # fmt: skip
            except (OSError, KeyError) as exc:
                raise HamError(f"cannot read glance table {str(path)!r}: {exc}") from None
            if verify:  # cheap (attributes, small arrays): streamed tables too
                _check_record(f, info, str(path))
        if stream:
            return cls(info, None, extras, _Stream(str(path), info))
        pressure = torch.from_numpy(np.stack(arrays).astype(np.float32, copy=False))
        pressure = pressure.view(len(info.objects), *info.grid_shape, info.taxels, info.taxels)
        return cls(info, pressure.to(device), extras)

    def to(self, device: str | torch.device) -> GlanceTable:
        if self.streamed:
            raise HamError(f"a streamed glance table stays on the CPU; accepted: cpu, not {device}")
        return GlanceTable(self.info, self.pressure.to(device), self.extras)

    def indices(self, q_x, q_phi) -> tuple[torch.Tensor, torch.Tensor]:
        from ham.world.glance import as_action

        qx = as_action("q_x", q_x, self.device)
        qp = as_action("q_phi", q_phi, self.device)
        return nearest_index(qx, self.grid), nearest_index(qp, self.grid)

    def lookup(self, object_ids, q_x, q_phi, *, check: bool = True) -> torch.Tensor:
        """Raw pressure ``(B, N, N)`` at the grid points closest to ``(q_x, q_phi)``.

        ``check=False`` skips input validation (the training loop's own samples are in range).
        """
        if self.pose_dims != PAPER_POSE_DIMS:
            raise HamError(
                f"lookup(q_x, q_phi) on a table over pose dims {','.join(self.pose_dims)}; "
                f"accepted: lookup_pose(ids, q) with q (B, {len(self.pose_dims)})"
            )
        if self.streamed:
            q = torch.stack([torch.as_tensor(q_x), torch.as_tensor(q_phi)], -1)
            return self.lookup_pose(object_ids, q, check=check)
        if check:
            from ham.world.glance import as_object_ids

            ids = as_object_ids(object_ids, self.n_objects, self.device)
            ix, ip = self.indices(q_x, q_phi)
        else:
            ids = object_ids
            ix, ip = nearest_index(q_x, self.grid), nearest_index(q_phi, self.grid)
        g, n = self.grid, self.taxels
        flat = self.pressure.view(-1, n * n)  # one gather of whole images: no per-axis indexing
        return flat.index_select(0, (ids * g + ix) * g + ip).view(-1, n, n)

    def pose_index(self, object_ids, q, *, check: bool = True) -> torch.Tensor:
        """The flat index ``object * P + pose`` of the grid point closest to each row of ``q``
        ``(B, k)`` (columns: :attr:`pose_dims`)."""
        from ham.world.glance import as_action, as_object_ids

        k = len(self.pose_dims)
        if check:
            ids = as_object_ids(object_ids, self.n_objects, self.device)
            q = torch.as_tensor(q, device=self.device)
            if q.ndim != 2 or q.shape[1] != k or q.shape[0] != ids.shape[0]:
                raise HamError(
                    f"poses of shape {tuple(q.shape)}; accepted: ({ids.shape[0]}, {k}) for the "
                    f"table's pose dims {','.join(self.pose_dims)}"
                )
            q = torch.stack(
                [as_action(f"q_{d}", q[:, i], self.device) for i, d in enumerate(self.pose_dims)],
                -1,
            )
        else:
            ids = object_ids
        flat = ids * self.info.poses
        if self._stride_t is not None and self._stride_t.device == q.device:
            # the same integers as the loop below, in a few kernels instead of 7 per dim
            return flat + (nearest_index(q, self.grid_shape[0]) * self._stride_t).sum(-1)
        for i, (g, stride) in enumerate(zip(self.grid_shape, self._strides, strict=True)):
            flat = flat + nearest_index(q[:, i], g) * stride
        return flat

    def lookup_pose(
        self, object_ids, q, *, check: bool = True, height: bool = False
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Raw pressure ``(B, N, N)`` at the grid points closest to the poses ``q`` ``(B, k)``
        (and the contact heights ``(B,)`` with ``height``). On the paper's table the same
        gather as :meth:`lookup`."""
        idx = self.pose_index(object_ids, q, check=check)
        n = self.taxels
        if self._stream is not None:
            pressure = self._stream.read(idx).view(-1, n, n)
        else:
            pressure = self.pressure.view(-1, n * n).index_select(0, idx).view(-1, n, n)
        if not height:
            return pressure
        return pressure, self.height.view(-1).index_select(0, idx)


class _Stream:
    """The images of a version-2 table on disk: memory-mapped when stored uncompressed, else
    read per batch (unique sorted pose indices, one read per object)."""

    def __init__(self, path: str, info: TableInfo) -> None:
        self.path, self.info = path, info
        self._file = h5py.File(path, "r")
        self._ds = [self._file[f"objects/{n}/pressure"] for n in info.objects]
        self._maps = None
        offsets = [ds.id.get_offset() for ds in self._ds]
        if info.compression == "none" and all(o is not None for o in offsets):
            shape = (info.poses, info.pressure_dim)
            self._maps = [np.memmap(path, np.float32, "r", o, shape) for o in offsets]

    def read(self, idx: torch.Tensor) -> torch.Tensor:
        """Images ``(B, N*N)`` at flat indices ``object * P + pose``."""
        poses = self.info.poses
        flat = idx.cpu().numpy()
        obj, pose = np.divmod(flat, poses)
        out = np.empty((len(flat), self.info.pressure_dim), np.float32)
        for o in np.unique(obj):
            rows = np.flatnonzero(obj == o)
            want, inverse = np.unique(pose[rows], return_inverse=True)
            if self._maps is not None:
                got = self._maps[o][want]
            else:
                got = self._ds[o][want].reshape(len(want), -1)  # h5py: increasing indices
            out[rows] = got[inverse]
        return torch.from_numpy(out)

    def close(self) -> None:
        self._file.close()


# --------------------------------------------------------------------------- authors' data
@checked_arguments
def import_authors(
    src: str | os.PathLike,
    out: str | os.PathLike,
    *,
    axes: str = "x,phi",
    command: str | None = None,
) -> Path:
    """Convert the authors' layout (``object_0``..``object_3``, each [201][201][256]) to a table.

    Their pad is the paper's (16 x 16 taxels, ``AUTHORS_TAXELS``): the table records the default
    :class:`ham.world.sensor.SensorConfig`.

    ``axes`` names the order of the first two axes in their file (``x,phi`` or ``phi,x``).
    Their images are stored as they are (the authors normalized them); force and z are unknown (NaN).
    """
    if axes not in ("x,phi", "phi,x"):
        raise HamError(f"axes = {axes!r}; accepted: x,phi or phi,x")
    out = check_output(out, (".h5", ".hdf5"), what="glance table")
    with _open(src) as f:
        arrays = []
        for i in range(len(AUTHORS_OBJECTS)):
            ds = f.get(f"object_{i}")
            if ds is None:
                raise HamError(
                    f"{str(src)!r} has no dataset object_{i}; expected object_0..object_3"
                )
            if ds.ndim != 3 or ds.shape[0] != ds.shape[1] or ds.shape[2] != AUTHORS_TAXELS**2:
                raise HamError(
                    f"{str(src)!r}: object_{i} has shape {ds.shape}; expected (grid, grid, 256)"
                )
            if ds.dtype.kind not in "biuf":  # complex lost its imaginary part, text was parsed
                raise HamError(
                    f"{str(src)!r}: object_{i} holds {ds.dtype} values; accepted: real pressures"
                )
            a = np.asarray(ds[...], dtype=np.float32)
            if axes == "phi,x":
                a = a.transpose(1, 0, 2)
            arrays.append(a.reshape(a.shape[0], a.shape[1], AUTHORS_TAXELS, AUTHORS_TAXELS))
            _check_pressure(str(src), f"object_{i}", arrays[-1])
    grid = arrays[0].shape[0]
    if any(a.shape[0] != grid for a in arrays):
        raise HamError(f"{str(src)!r}: the objects have different grid sizes")
    world = WorldConfig(sensor=SensorConfig(taxels=AUTHORS_TAXELS))
    command = command or _python_command(
        f"ham.world.table.import_authors({str(src)!r}, {str(out)!r}, axes={axes!r})"
    )

    simulator = {"simulator": "gazebo (authors' data set)", "axes": axes}

    def write(tmp: Path) -> None:
        with h5py.File(tmp, "w") as g:
            _write_images(g, list(AUTHORS_OBJECTS), arrays, grid, world, simulator,
                          f"authors:{Path(src).name}", command)  # fmt: skip

    return atomic_write(out, write, what="glance table")


@checked_arguments
def import_recorded(
    src: str | os.PathLike | list | tuple,
    out: str | os.PathLike,
    *,
    pose_dims: str | tuple[str, ...] = PAPER_POSE_DIMS,
    compression: str | None = None,
    command: str | None = None,
) -> Path:
    """A table from recorded glances: a real pad's, or another simulator's. ``src`` is a NumPy
    ``.npz`` file (or a list of them, their objects in turn: objects recorded on different days)
    with one array per object, named by it, in class order: ``(G_1, .., G_k, N, N)``, the ``N x
    N`` image at each point of a grid over the ``k`` ``pose_dims`` (default the paper's ``x,
    phi``; e.g. ``x,y,phi,phi_y`` for the extended glance), each axis from -1 to 1
    (:func:`grid_values`), pressures >= 0 (any unit: the normalization makes them scale-free).
    An array ``NAME.height`` ``(G_1, .., G_k)`` (m) beside an object's gives its contact
    heights; force is unknown (NaN); names starting with ``__`` are not objects (the recorder's
    ``__spec__``, :mod:`ham.world.recorder`). A square ``(x, phi)`` grid is written in the
    paper's format 1, any other in format 2 (``compression``: gzip by default, lzf or none, as
    :func:`build_table`). Then ``ham train --table``, ``--init-from`` (fine-tuning on it) and
    ``ham evaluate --transfer-table`` take it."""
    out = check_output(out, (".h5", ".hdf5"), what="glance table")
    dims = check_pose_dims(pose_dims, "pose_dims")
    k = len(dims)
    if compression is not None and compression not in COMPRESSIONS:
        raise HamError(f"compression = {compression!r}; accepted: {', '.join(COMPRESSIONS)}")
    names, arrays, heights, files = load_recorded(src, dims)
    shape, taxels = grid_shape_for(arrays[0].shape[:k], dims), arrays[0].shape[k]
    paper = is_paper_layout(dims, shape)
    if paper and compression is not None:  # said, not silently ignored
        raise HamError(
            f"compression = {compression!r} for the paper's (x, phi) table, which is stored "
            "uncompressed; accepted: a compression for a table over other pose dims (format 2)"
        )
    world = WorldConfig(sensor=SensorConfig(taxels=taxels), pose_dims=dims)
    given = repr(str(files[0])) if len(files) == 1 else repr([str(f) for f in files])
    call = f"ham.world.table.import_recorded({given}, {str(out)!r}"
    if not paper:
        call += f", pose_dims={','.join(dims)!r}"
    command = command or _python_command(call + ")")
    file_names = [Path(f).name for f in files]
    simulator = {"simulator": "recorded", "file": ", ".join(file_names)}
    layout = None if paper else (dims, shape, compression or "gzip")

    def write(tmp: Path) -> None:
        with h5py.File(tmp, "w") as g:
            _write_images(g, names, arrays, shape[0], world, simulator,
                          f"recorded:{','.join(file_names)}", command, heights, layout)  # fmt: skip

    return atomic_write(out, write, what="glance table")


def load_recorded(
    src, dims: tuple[str, ...]
) -> tuple[list[str], list[np.ndarray], list[np.ndarray | None], list]:
    """The recorded glances of one ``.npz`` file or a list of them (module doc of
    :func:`import_recorded`), checked: the objects' names in file order, their ``(G_1, .., G_k,
    N, N)`` float32 images over the ``dims`` grid, their heights (``None`` where not recorded)
    and the files; a one-line :class:`HamError` names what is wrong."""
    k = len(dims)
    axes = ", ".join(f"G_{d}" for d in dims)
    accepted = f"accepted: an .npz file of one ({axes}, N, N) array per object"
    files = list(src) if isinstance(src, (list, tuple)) else [src]
    if not files or not all(isinstance(f, (str, os.PathLike)) for f in files):
        raise HamError(f"recorded glances {src!r}; accepted: an .npz file or a list of them")
    stored: dict[str, np.ndarray] = {}
    origin: dict[str, str] = {}  # each array's file, for the messages
    for one in files:
        for name, a in _read_recorded(one, accepted).items():
            if name in stored:
                raise HamError(f"{name} is in both {origin[name]!r} and {str(one)!r}; accepted: "
                               "each object (and its NAME.height) in one file")  # fmt: skip
            stored[name], origin[name] = a, str(one)
    where = str(files[0]) if len(files) == 1 else ", ".join(map(str, files))
    names = [n for n in stored if not n.endswith(".height")]
    if not names:
        raise HamError(f"{where!r} holds no object's images; accepted: one ({axes}, N, N) "
                       "array per object, named by it")  # fmt: skip
    arrays, heights = [], []
    for name in names:
        a = stored[name]
        if a.ndim != k + 2 or a.shape[k] != a.shape[k + 1] or min(a.shape[:k]) < 2:
            raise HamError(f"{origin[name]!r}: {name} has shape {a.shape}; accepted: ({axes}, "
                           f"N, N) for pose dims {','.join(dims)}, G >= 2 grid points per axis, "
                           "N x N taxels")  # fmt: skip
        if a.dtype.kind not in "biuf":
            raise HamError(f"{origin[name]!r}: {name} holds {a.dtype} values; accepted: real "
                           "pressures")  # fmt: skip
        arrays.append(np.ascontiguousarray(a, dtype=np.float32))
        _check_pressure(origin[name], name, arrays[-1])
        h = stored.get(f"{name}.height")
        if h is not None:
            if h.shape != a.shape[:k] or h.dtype.kind not in "biuf" or not np.isfinite(h).all():
                raise HamError(f"{origin[name]!r}: {name}.height has shape {h.shape} "
                               f"({h.dtype}); accepted: finite heights (m) of shape "
                               f"{a.shape[:k]}")  # fmt: skip
            h = np.asarray(h, dtype=np.float32)
        heights.append(h)
    stray = [n for n in stored if n.endswith(".height") and n.removesuffix(".height") not in names]
    if stray:
        raise HamError(f"{origin[stray[0]]!r}: {stray[0]} belongs to no object's images; "
                       "accepted: NAME.height beside an array NAME")  # fmt: skip
    if any(a.shape != arrays[0].shape for a in arrays):
        shapes = ", ".join(f"{n} {a.shape}" for n, a in zip(names, arrays, strict=True))
        raise HamError(f"{where!r}: the objects' arrays differ in shape ({shapes}); "
                       "accepted: one grid and one pad for all")  # fmt: skip
    return names, arrays, heights, files


def _read_recorded(src, accepted: str) -> dict[str, np.ndarray]:
    """The arrays of one recorded-glances ``.npz`` file (not its ``__`` names), or a one-line
    :class:`HamError` naming it."""
    if Path(src).is_dir():
        raise HamError(f"recorded glances {str(src)!r} is a folder; {accepted}")
    if Path(src).is_file() and not zipfile.is_zipfile(src):  # np.load would read it as a pickle
        raise HamError(f"recorded glances {str(src)!r} is not an .npz file (a zip of arrays); "
                       f"{accepted}")  # fmt: skip
    try:
        with np.load(src, allow_pickle=False) as f:
            stored = {k: f[k] for k in f.files}
    except (OSError, ValueError, EOFError) as exc:  # zipfile.BadZipFile is an OSError
        raise HamError(f"cannot read recorded glances {str(src)!r}: {exc}; {accepted}") from None
    if "__done__" in stored:  # record_glances' progress file, not its recording
        raise HamError(f"recorded glances {str(src)!r} is a partial recording that record_glances "
                       "has not finished; accepted: the finished recording (OUT.npz, written when "
                       "every glance is in)")  # fmt: skip
    return {k: a for k, a in stored.items() if not k.startswith("__")}


def _write_images(
    g,
    names,
    arrays,
    grid,
    world,
    simulator,
    source,
    command,
    heights=None,
    layout=None,
    forces=None,
) -> None:
    """Images over a pose grid as a ham table in the open HDF5 file ``g`` (the authors' data
    set, recorded glances, a calibrated table); forces and heights where given, else unknown
    (NaN). ``layout``: ``None``, the
    paper's ``grid x grid`` (format 1), or ``(pose_dims, grid_shape, compression)`` (format 2,
    the images stored flat over the lattice as :func:`build_table` stores them)."""
    attrs = dict(format=FORMAT, format_version=FORMAT_VERSION, grid=grid)
    if layout is not None:
        dims, shape, compression = layout
        attrs.update(format_version=FORMAT_VERSION_GRID, grid_shape=json.dumps(list(shape)),
                     pose_dims=json.dumps(list(dims)), compression=compression)  # fmt: skip
    g.attrs.update(
        **attrs,
        q_range=json.dumps([-1.0, 1.0]),
        objects=json.dumps(list(names)),
        world=json.dumps(world.to_dict(), sort_keys=True),
        sensor=json.dumps(world.sensor.to_dict(), sort_keys=True),
        geometry=json.dumps({}),
        simulator=json.dumps(simulator),
        ham_version=ham.__version__,
        source=source,
        command=command,
        created=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    )
    for i, (name, a) in enumerate(zip(names, arrays, strict=True)):
        h = None if heights is None else heights[i]
        grp = g.create_group(f"objects/{name}")
        if layout is None:
            poses, key, opts = (grid, grid), "z", {}
        else:
            poses, key = (int(np.prod(shape)),), "height"
            a = a.reshape(poses[0], *a.shape[-2:])
            h = None if h is None else h.reshape(poses)
            comp = None if compression == "none" else compression
            opts = dict(compression=comp, chunks=True) if comp else {}
        if opts:
            n = a.shape[-1]
            rows = max(1, min(poses[0], 262144 // (4 * n * n)))  # ~256 KB chunks, as built
            grp.create_dataset("pressure", data=a, chunks=(rows, n, n), compression=comp)
        else:
            grp.create_dataset("pressure", data=a)
        force = np.full(poses, np.nan, np.float32) if forces is None else forces[i].reshape(poses)
        grp.create_dataset("force", data=force, **opts)
        grp.create_dataset(key, data=np.full(poses, np.nan, np.float32) if h is None else h,
                           **opts)  # fmt: skip
        grp.create_dataset("contact", data=a.reshape(*poses, -1).max(-1) > 0, **opts)
    g.attrs["checksum"] = _checksum(g, list(names))
    g.attrs["record_checksum"] = _record_checksum(g, list(names))
