"""Glance tables: the paper's pre-recorded data set (section "Creation of the dataset").

For every object, glances on a ``grid x grid`` lattice of normalized poses
``q_x, q_phi in {-1, -1 + 2/(grid-1), ..., 1}`` (the paper: 201 x 201, steps 0.01 in x and
0.01 pi in phi). A pose the agent asks for is answered by the closest grid point.

File layout (HDF5, self-describing)::

    /                       attrs: format, format_version, grid, q_range, objects (JSON),
                                   world (JSON WorldConfig), sensor (JSON SensorConfig, also in
                                   world), geometry (JSON outlines), simulator description (JSON),
                                   ham_version, command, created, checksum
    /objects/<name>/pressure  (grid, grid, N, N) float32, raw Pa; axis 0 = q_x index, 1 = q_phi;
                              N = the sensor's taxels (16)
    /objects/<name>/force     (grid, grid) float32, N (NaN where unknown, e.g. imported data)
    /objects/<name>/z         (grid, grid) float32, m
    /objects/<name>/contact   (grid, grid) bool

Files are written atomically: a build writes ``FILE.partial`` (resumable: finished q_x rows are
marked in ``/progress``) and renames it to ``FILE`` only when complete and checksummed.

Reading checks a table before use (:meth:`GlanceTable.load`, :func:`verify_table`, ``ham table
verify``): its attributes and dataset shapes, at least one object, finite non-negative
pressures, and the sha256 checksum of the pressures. On the paper's 201 x 201 table (165 MB)
the checksum adds about 0.2 s to a 0.1 s load (warm cache, one core), so loads keep it on.
"""

from __future__ import annotations

import hashlib
import json
import os
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
import torch
from tqdm.auto import tqdm

import ham
from ham.errors import HamError
from ham.world.config import WorldConfig, make_simulator
from ham.world.files import atomic_write, check_output
from ham.world.objects import load_objects
from ham.world.sensor import SensorConfig

FORMAT = "ham-glance-table"
FORMAT_VERSION = 1
AUTHORS_OBJECTS = ("box", "ramp_up", "convex", "ramp_down")
#: The authors' data set is the paper's pad: 16 x 16 taxels, flattened to 256 values.
AUTHORS_TAXELS = 16


def grid_values(grid: int) -> np.ndarray:
    """The normalized pose values of a grid axis: ``grid`` points from -1 to 1."""
    return np.linspace(-1.0, 1.0, grid)


def nearest_index(q: torch.Tensor, grid: int) -> torch.Tensor:
    """Index of the closest grid point to ``q`` in [-1, 1] (exact on grid points)."""
    return torch.round((q + 1.0) * (0.5 * (grid - 1))).long().clamp_(0, grid - 1)


def _check_grid(grid: int) -> None:
    if not (isinstance(grid, int) and 2 <= grid <= 2001):
        raise HamError(f"grid = {grid!r}; accepted: an integer 2..2001 (the paper uses 201)")


def _python_command(call: str) -> str:
    """The command of a table written through the Python API: the program and the call."""
    argv = [a for a in sys.argv if a]
    return f"python {shlex.join(argv)}: {call}" if argv else f"python: {call}"


def _check_pressure(path: str, name: str, a: np.ndarray) -> None:
    """Finite, non-negative pressures (Pa), or a :class:`HamError` naming the first bad value."""
    # two reductions (NaN propagates into both) instead of a mask over 16 M values
    lo, hi = a.min(initial=0.0), a.max(initial=0.0)
    if np.isfinite(lo) and np.isfinite(hi) and lo >= 0:
        return
    i = tuple(int(k) for k in np.argwhere(~np.isfinite(a) | (a < 0))[0])
    raise HamError(
        f"glance table {path!r} is corrupt: objects/{name}/pressure holds {float(a[i])} at index "
        f"{i}; accepted: finite pressures >= 0 Pa"
    )


def _checksum(f: h5py.File, names: list[str]) -> str:
    h = hashlib.sha256()
    for name in names:
        h.update(np.ascontiguousarray(f[f"objects/{name}/pressure"][...]).tobytes())
    return h.hexdigest()


# --------------------------------------------------------------------------- build
def build_table(
    world: WorldConfig,
    grid: int,
    out: str | os.PathLike,
    *,
    batch: int | None = None,
    progress: bool = True,
    command: str | None = None,
    **sim_kwargs,
) -> Path:
    """Record ``grid x grid`` glances per object of ``world`` into the HDF5 file ``out``.

    Resumes from ``out.partial`` when one exists for the same world and grid. ``command`` is
    recorded in the file (the CLI passes its argv; default: the Python program and this call).
    The world, and so any objects file it was built from (name, sha256, text), is recorded too.
    """
    _check_grid(grid)
    out = check_output(out, (".h5", ".hdf5"), what="glance table")
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".partial")
    objs = world.resolve_objects()
    names = [o.name for o in objs]
    world_json = json.dumps(world.to_dict(), sort_keys=True)
    sim = make_simulator(world, **sim_kwargs)
    n_tax = world.sensor.taxels
    q = grid_values(grid)
    # Rows of q_x per simulator call: the fast model takes whole objects, slow engines less.
    batch = batch or (grid * grid if sim.name == "fast" else 16 * grid)
    rows_per_call = max(1, batch // grid)

    mode = "a" if partial.exists() else "w"
    try:
        f = h5py.File(partial, mode)
    except OSError as exc:
        raise HamError(f"cannot write glance table {partial}: {exc}") from None
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
                q_range=json.dumps([-1.0, 1.0]),
                objects=json.dumps(names),
                world=world_json,
                sensor=json.dumps(world.sensor.to_dict(), sort_keys=True),
                geometry=json.dumps({o.name: o.outline().tolist() for o in objs}),
                simulator=json.dumps(sim.describe(), sort_keys=True, default=str),
                ham_version=ham.__version__,
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
        f.attrs["command"] = command or _python_command(
            f"ham.world.table.build_table(grid={grid}, out={str(out)!r})"
        )
        f.attrs["created"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
        f.attrs["checksum"] = _checksum(f, names)
        del f["progress"]
    os.replace(partial, out)
    return out


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

    @property
    def taxels(self) -> int:
        """Cells per side of the table's images (16)."""
        return int(self.sensor.get("taxels", 16))

    @property
    def pressure_dim(self) -> int:
        """Values in one flattened image, the input size of a model that reads this table."""
        return self.taxels**2

    def to_dict(self) -> dict:
        return dict(self.__dict__)


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
    if int(a.get("format_version", -1)) != FORMAT_VERSION:
        raise HamError(
            f"{path!r} has table format version {a.get('format_version')}; accepted: {FORMAT_VERSION}"
        )
    try:
        grid = int(a["grid"])
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
    if not 2 <= grid <= 2001:
        raise HamError(f"glance table {path!r} has grid {grid}; accepted: 2..2001")
    n = sensor["taxels"]
    for name in names:
        for key, shape in (
            ("pressure", (grid, grid, n, n)),
            ("force", (grid, grid)),
            ("z", (grid, grid)),
            ("contact", (grid, grid)),
        ):
            ds = f.get(f"objects/{name}/{key}")
            if ds is None:
                raise HamError(f"{path!r}: objects/{name}/{key} is missing; a glance table has one")
            if ds.shape != shape:
                raise HamError(
                    f"{path!r}: objects/{name}/{key} has shape {ds.shape}, expected {shape}"
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
        source=str(a.get("source", "ham")),
        sensor=sensor,
    )


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


def verify_table(path: str | os.PathLike) -> TableInfo:
    """Check a table completely (``ham table verify``): attributes, shapes, at least one object,
    finite non-negative pressures and the sha256 checksum; a :class:`HamError` names the problem."""
    with _open(path) as f:
        info = _read_info(f, str(path))
        _read_pressure(f, info, str(path), verify=True)
    return info


class GlanceTable:
    """A loaded glance table with vectorized nearest-grid-point lookup (CPU or CUDA).

    ``pressure`` is a ``(n_objects, grid, grid, N, N)`` float32 tensor of raw pressure, ``N`` the
    recorded sensor's ``taxels`` (16).
    """

    def __init__(self, info: TableInfo, pressure: torch.Tensor, extras: dict[str, np.ndarray]):
        self.info = info
        self.grid = info.grid
        self.objects = list(info.objects)
        self.n_objects = len(self.objects)
        self.taxels = info.taxels
        self.pressure_dim = info.pressure_dim
        self.pressure = pressure
        self.extras = extras

    @property
    def world(self) -> WorldConfig:
        """The world the table was built in (its objects file's objects are registered)."""
        return WorldConfig.from_dict(self.info.world)

    @property
    def device(self) -> torch.device:
        return self.pressure.device

    @classmethod
    def load(
        cls, path: str | os.PathLike, *, verify: bool = True, device: str = "cpu"
    ) -> GlanceTable:
        """Read ``path``; refuse truncated, corrupt or mismatched files with a clear error.

        Structure, finite non-negative pressures and (with ``verify``, the default) the
        checksum are checked: see the module doc for the cost. Registers the objects of the
        objects file the table was built from (hash verified).
        """
        from ham.world.devices import check_device

        device = check_device(device)
        with _open(path) as f:
            info = _read_info(f, str(path))
            if info.world.get("objects_file") is not None:
                load_objects(info.world["objects_file"])
            arrays = _read_pressure(f, info, str(path), verify)
            try:
                extras = {
                    key: np.stack([f[f"objects/{n}/{key}"][...] for n in info.objects])
                    for key in ("force", "z", "contact")
                }
            except (OSError, KeyError) as exc:
                raise HamError(f"cannot read glance table {str(path)!r}: {exc}") from None
        pressure = torch.from_numpy(np.stack(arrays).astype(np.float32, copy=False)).to(device)
        return cls(info, pressure, extras)

    def to(self, device: str | torch.device) -> GlanceTable:
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


# --------------------------------------------------------------------------- authors' data
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

    def write(tmp: Path) -> None:
        with h5py.File(tmp, "w") as g:
            _write_authors(g, src, arrays, grid, axes, world, command)

    return atomic_write(out, write, what="glance table")


def _write_authors(g, src, arrays, grid, axes, world, command) -> None:
    """The authors' arrays as a ham table in the open HDF5 file ``g``."""
    g.attrs.update(
        format=FORMAT,
        format_version=FORMAT_VERSION,
        grid=grid,
        q_range=json.dumps([-1.0, 1.0]),
        objects=json.dumps(list(AUTHORS_OBJECTS)),
        world=json.dumps(world.to_dict(), sort_keys=True),
        sensor=json.dumps(world.sensor.to_dict(), sort_keys=True),
        geometry=json.dumps({}),
        simulator=json.dumps({"simulator": "gazebo (authors' data set)", "axes": axes}),
        ham_version=ham.__version__,
        source=f"authors:{Path(src).name}",
        command=command,
        created=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    )
    for name, a in zip(AUTHORS_OBJECTS, arrays, strict=True):
        grp = g.create_group(f"objects/{name}")
        grp.create_dataset("pressure", data=a)
        grp.create_dataset("force", data=np.full((grid, grid), np.nan, np.float32))
        grp.create_dataset("z", data=np.full((grid, grid), np.nan, np.float32))
        grp.create_dataset("contact", data=a.reshape(grid, grid, -1).max(-1) > 0)
    g.attrs["checksum"] = _checksum(g, list(AUTHORS_OBJECTS))
