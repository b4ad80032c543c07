"""Read-out calibration: a simulator's glance table carried onto a pad by a read-out fitted to
a few of the pad's recorded glances (``ham table calibrate``).

A simulator and a pad feel the same contact but read it out in their own ways: the fast
simulator's foam taxels, the Gazebo plugin's few contact points spread by 5 mm, a real pad's
foam, cross-talk and gain. A read-out that is linear and the same at every taxel is a
convolution, so the pad's image is modelled as ``K * s + b``: the simulator's image ``s`` at the
same pose, convolved with a ``k x k`` kernel ``K`` (zero padding), plus a constant ``b``, read
as no less than 0 (a pad reads no negative pressure). ``K`` and ``b`` are fitted by least
squares over every taxel of every recorded glance, paired with the simulator's glance at the
table's grid point nearest the recorded pose. The fitted read-out then carries every glance of
the table to the pad, between the recorded poses too: what a coarse recorded grid alone
cannot give (docs/sim_to_real.md). The read-out belongs to the pad and the kind of contact,
not to one object: the recorded glances may be of a few of the table's objects, and
:func:`carry_readout` applies a read-out fitted before to another table (``--readout-from``).
Measured live: it carries across objects that touch the pad alike (one of the paper's four
profiles for all four; 3 of the next world's 12 height fields for all), not from the paper's
tilted profiles to the next world's height fields under a flat pad, or back.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import torch

from ham.errors import HamError, brief, checked_arguments
from ham.world.config import WorldConfig
from ham.world.files import atomic_write, check_output
from ham.world.table import (
    FORMAT_VERSION,
    MAX_MEMORY,
    MAX_PRESSURE,
    _check_pressure,
    _check_record,
    _open,
    _python_command,
    _read_info,
    _write_images,
    bad_pressure,
    grid_values,
    load_recorded,
)

#: Images per block when a read-out is fitted or applied (bounds the patch matrices' memory).
BLOCK = 2048
#: Folds of the read-out's cross-validation (fewer when fewer glances are recorded).
FOLDS = 10


@dataclass(frozen=True)
class Readout:
    """A pad's read-out of a simulator's images: ``max(K * s + b, 0)``.

    ``kernel`` is ``(k, k)``, ``bias`` in the pad's unit; ``r2``: the share of the recorded
    glances' variance (over all their taxels) that the fitted read-out explains; ``glances``:
    how many recorded glances it was fitted to; ``r2_held_out``: the same share with each
    glance predicted by a read-out fitted without it (``FOLDS``-fold cross-validation, glance
    ``j`` in fold ``j % FOLDS``; ``None`` for one glance): how well the read-out carries to
    poses not recorded."""

    kernel: np.ndarray
    bias: float
    r2: float
    glances: int
    r2_held_out: float | None = None

    def apply(self, images: np.ndarray) -> np.ndarray:
        """The pad's images ``(..., N, N)`` (float32) of the simulator's ``images``."""
        shape = images.shape
        flat = np.asarray(images).reshape(-1, 1, *shape[-2:])
        k = self.kernel.shape[0]
        weight = torch.from_numpy(self.kernel)[None, None]
        out = np.empty(flat.shape, np.float32)
        for i in range(0, len(flat), BLOCK):  # float64 a block at a time, not a copy of all
            x = torch.from_numpy(np.asarray(flat[i : i + BLOCK], dtype=np.float64))
            y = torch.nn.functional.conv2d(x, weight, padding=k // 2) + self.bias
            out[i : i + BLOCK] = y.clamp_min(0).numpy()
        return out.reshape(shape)

    def to_dict(self) -> dict:
        return {"kernel": self.kernel.tolist(), "bias": self.bias, "r2": self.r2,
                "r2_held_out": self.r2_held_out, "glances": self.glances}  # fmt: skip

    @classmethod
    def from_dict(cls, d: dict, where: str) -> Readout:
        """The read-out :meth:`to_dict` wrote (in the table ``where``), or a HamError."""
        try:
            kernel = np.asarray(d["kernel"], dtype=np.float64)
            bias, r2, glances = float(d["bias"]), float(d["r2"]), int(d["glances"])
            held = d.get("r2_held_out")
            held = None if held is None else float(held)
        except (KeyError, TypeError, ValueError) as exc:
            raise HamError(f"glance table {where!r}: its read-out is incomplete ({exc}); "
                           "accepted: a table written by ham table calibrate") from None  # fmt: skip
        k = kernel.shape[0] if kernel.ndim == 2 else 0
        if kernel.shape != (k, k) or k % 2 == 0 or not (np.isfinite(kernel).all()
                                                        and np.isfinite(bias)):  # fmt: skip
            raise HamError(f"glance table {where!r}: its read-out's kernel {kernel.shape} or "
                           f"bias {bias} is not one; accepted: a finite odd square kernel "
                           "and bias, as ham table calibrate writes them")  # fmt: skip
        return cls(kernel, bias, r2, glances, held)


def _patches(images: np.ndarray, k: int) -> np.ndarray:
    """Each taxel's ``k x k`` neighbourhood (zero padded) as a row: ``(M*N*N, k*k)``."""
    x = torch.from_numpy(np.ascontiguousarray(images, dtype=np.float64))[:, None]
    cols = torch.nn.functional.unfold(x, k, padding=k // 2)  # (M, k*k, N*N)
    return cols.transpose(1, 2).reshape(-1, k * k).numpy()


def check_kernel(kernel, taxels: int) -> int:
    """``kernel`` as an odd int from 1 to ``2 * taxels - 1``, or a HamError naming it."""
    top = 2 * taxels - 1
    if isinstance(kernel, bool) or not isinstance(kernel, (int, np.integer)):
        raise HamError(f"kernel = {kernel!r}; accepted: an odd integer from 1 to {top}")
    if not (1 <= kernel <= top and kernel % 2 == 1):
        raise HamError(f"kernel = {kernel}; accepted: an odd integer from 1 to {top} (the "
                       f"pad's {taxels} x {taxels} taxels)")  # fmt: skip
    return int(kernel)


@checked_arguments
def fit_readout(simulated: np.ndarray, recorded: np.ndarray, kernel: int = 9) -> Readout:
    """The least-squares read-out (module doc) taking ``simulated`` images ``(M, N, N)`` to the
    ``recorded`` ones at the same poses: the normal equations summed block by block, solved in
    float64 (a minimum-norm solution where they are singular)."""
    for name, a in (("simulated", simulated), ("recorded", recorded)):
        if not isinstance(a, np.ndarray) or a.dtype.kind not in "biuf" or a.ndim != 3:
            raise HamError(f"{name} = {brief(a)}; accepted: a real (M, N, N) array of images")
        if not np.isfinite(a).all():
            raise HamError(f"{name} images hold NaN or infinite values; accepted: finite ones")
    if simulated.shape != recorded.shape:
        raise HamError(f"simulated images {simulated.shape} and recorded {recorded.shape}; "
                       "accepted: two (M, N, N) arrays of the same shape")  # fmt: skip
    kernel = check_kernel(kernel, simulated.shape[-1])
    n, m = kernel * kernel + 1, len(simulated)
    folds = min(m, FOLDS)
    # the normal equations per fold (glance j in fold j % folds), summed for the fit
    gram, moment, square = np.zeros((folds, n, n)), np.zeros((folds, n)), np.zeros(folds)
    total, count = 0.0, 0
    pixels = simulated.shape[-1] * simulated.shape[-2]
    for i in range(0, m, BLOCK):
        x = _patches(simulated[i : i + BLOCK], kernel)
        x = np.concatenate([x, np.ones((len(x), 1))], 1)
        y = np.asarray(recorded[i : i + BLOCK], dtype=np.float64).reshape(-1)
        fold = np.repeat((np.arange(i, i + len(x) // pixels)) % folds, pixels)
        for f in np.unique(fold):
            rows = fold == f
            gram[f] += x[rows].T @ x[rows]
            moment[f] += x[rows].T @ y[rows]
            square[f] += y[rows] @ y[rows]
        total, count = total + y.sum(), count + len(y)
    variance = square.sum() - total * total / count
    if not variance > 0:
        raise HamError("the recorded glances are all the same value (no contact read?); "
                       "accepted: glances that press the objects")  # fmt: skip

    def residual(w: np.ndarray, g: np.ndarray, mo: np.ndarray, sq: float) -> float:
        """The residual sum of squares from normal equations: |y|^2 - 2 w.X'y + w.X'X w."""
        return max(sq - 2 * w @ mo + w @ g @ w, 0.0)

    w = np.linalg.lstsq(gram.sum(0), moment.sum(0), rcond=None)[0]
    r2 = 1 - residual(w, gram.sum(0), moment.sum(0), square.sum()) / variance
    held_out = None
    if folds > 1:  # each fold predicted by the read-out fitted to the others
        errors = 0.0
        for f in range(folds):
            rest = np.linalg.lstsq(gram.sum(0) - gram[f], moment.sum(0) - moment[f],
                                   rcond=None)[0]  # fmt: skip
            errors += residual(rest, gram[f], moment[f], square[f])
        held_out = float(1 - errors / variance)
    return Readout(kernel=w[:-1].reshape(kernel, kernel), bias=float(w[-1]), r2=float(r2),
                   glances=m, r2_held_out=held_out)  # fmt: skip


@checked_arguments
def calibrate_table(
    table: str | os.PathLike,
    recorded: str | os.PathLike | list | tuple,
    out: str | os.PathLike,
    *,
    kernel: int = 9,
    command: str | None = None,
) -> tuple[Path, Readout]:
    """The simulator's ``table`` carried onto a pad (module doc): a read-out fitted to the
    pad's ``recorded`` glances (an ``.npz`` file or a list of them, as
    :func:`ham.world.table.import_recorded` reads them, over a grid of the table's pose dims),
    applied to every glance of the table. The glances may be of some of the table's objects
    only, each named by it: the read-out carries the objects never recorded too, where they
    touch the pad as the recorded ones do (module doc). The new table ``out`` has the table's objects, grid, world, forces and
    heights and the pad's images, its ``simulator`` attribute names the read-out; returns it
    with the :class:`Readout`."""
    out = check_output(out, (".h5", ".hdf5"), what="glance table")
    info, sim, forces, heights = _read_simulated(table, lambda info: check_kernel(kernel,
                                                                                  info.taxels))  # fmt: skip
    kernel = int(kernel)
    names, pad, _, files = load_recorded(recorded, info.pose_dims)
    unknown = [n for n in names if n not in info.objects]
    if unknown:
        raise HamError(f"recorded glances of {', '.join(unknown)}, which {str(table)!r} "
                       f"does not hold; accepted: objects of it: "
                       f"{', '.join(info.objects)}")  # fmt: skip
    if pad[0].shape[-1] != info.taxels:
        n = pad[0].shape[-1]
        raise HamError(f"recorded {n} x {n} images; accepted: the {info.taxels} x "
                       f"{info.taxels} of {str(table)!r}")  # fmt: skip
    # each recorded pose's nearest grid point of the table, and how far it lies from it
    grid = tuple(info.grid_shape)
    recorded_grid = pad[0].shape[: len(grid)]
    nearest, offset = [], 0.0
    for g, s in zip(recorded_grid, grid, strict=True):
        q, table_q = grid_values(g), grid_values(s)
        i = np.abs(q[:, None] - table_q[None, :]).argmin(1)
        nearest.append(i)
        offset = max(offset, float(np.abs(table_q[i] - q).max()))
    at = np.ix_(*nearest)
    simulated = np.concatenate([sim[info.objects.index(n)][at].reshape(-1, info.taxels,
                                                                      info.taxels)
                                for n in names])  # fmt: skip
    pads = np.concatenate([a.reshape(-1, info.taxels, info.taxels) for a in pad])
    readout = fit_readout(simulated, pads, kernel)
    file_names = [Path(p).name for p in files]
    simulator = {
        "simulator": "calibrated",
        "table": info.simulator,
        "table_source": info.source,
        "recorded": ", ".join(file_names),
        "recorded_objects": names,
        "recorded_grid": list(recorded_grid),
        "pose_offset": offset,
        "readout": readout.to_dict(),
    }
    given = repr(str(files[0])) if len(files) == 1 else repr([str(p) for p in files])
    command = command or _python_command(
        f"ham.world.calibration.calibrate_table({str(table)!r}, {given}, {str(out)!r}, "
        f"kernel={kernel})"
    )
    source = f"calibrated:{Path(table).name}+{','.join(file_names)}"
    path = _write_calibrated(out, info, sim, forces, heights, readout, simulator, source, command)
    return path, readout


@checked_arguments
def carry_readout(
    table: str | os.PathLike,
    calibrated: str | os.PathLike,
    out: str | os.PathLike,
    *,
    command: str | None = None,
) -> tuple[Path, Readout]:
    """The simulator's ``table`` carried onto a pad by the read-out fitted before, for another
    table (``calibrated``, written by :func:`calibrate_table`; ``ham table calibrate TABLE
    --readout-from CALIBRATED``): other objects of the same kind of contact, another grid. The
    pad's taxels must be the table's; returns the new table and the read-out. Across kinds of
    contact it does not carry (module doc)."""
    out = check_output(out, (".h5", ".hdf5"), what="glance table")
    with _open(calibrated) as f:
        theirs = _read_info(f, str(calibrated))
        _check_record(f, theirs, str(calibrated))  # its read-out is in the checked attributes
    made = theirs.simulator if isinstance(theirs.simulator, dict) else {}
    if made.get("simulator") != "calibrated" or not isinstance(made.get("readout"), dict):
        raise HamError(f"glance table {str(calibrated)!r} was not made by ham table calibrate "
                       "(no read-out in it); accepted: a calibrated table")  # fmt: skip
    readout = Readout.from_dict(made["readout"], str(calibrated))

    def check(info) -> None:
        if info.taxels != theirs.taxels:
            raise HamError(f"the read-out of {str(calibrated)!r} reads {theirs.taxels} x "
                           f"{theirs.taxels} images; accepted: a table of that pad, not "
                           f"{str(table)!r}'s {info.taxels} x {info.taxels}")  # fmt: skip

    info, sim, forces, heights = _read_simulated(table, check)
    simulator = {key: made[key] for key in made if key not in ("table", "table_source")}
    simulator.update(table=info.simulator, table_source=info.source,
                     readout_from=Path(calibrated).name)  # fmt: skip
    command = command or _python_command(
        f"ham.world.calibration.carry_readout({str(table)!r}, {str(calibrated)!r}, {str(out)!r})"
    )
    source = f"calibrated:{Path(table).name}+{Path(calibrated).name}"
    path = _write_calibrated(out, info, sim, forces, heights, readout, simulator, source, command)
    return path, readout


def _read_simulated(table, check) -> tuple:
    """The simulator's ``table``: its info, and each object's images ``(*grid, N, N)``, forces
    and heights, checked (``check(info)`` first, then the size and every pressure)."""
    with _open(table) as f:
        info = _read_info(f, str(table))
        check(info)
        size = info.poses * len(info.objects) * info.pressure_dim * 4
        if size > MAX_MEMORY:
            raise HamError(f"glance table {str(table)!r} holds {size / 1024**3:.1f} GiB of "
                           f"images; accepted: tables up to {MAX_MEMORY / 1024**3:.0f} GiB "
                           "(calibrate holds one in memory)")  # fmt: skip
        heights_key = "z" if info.format_version == FORMAT_VERSION else "height"
        grid = tuple(info.grid_shape)
        sim, forces, heights = [], [], []
        for name in info.objects:
            group = f[f"objects/{name}"]
            sim.append(group["pressure"][...].reshape(*grid, info.taxels, info.taxels))
            _check_pressure(str(table), name, sim[-1])  # a corrupt table is refused
            forces.append(group["force"][...].reshape(grid))
            heights.append(group[heights_key][...].reshape(grid))
    return info, sim, forces, heights


def _write_calibrated(out, info, sim, forces, heights, readout, simulator, source, command):
    """``readout`` applied to every image of ``sim``, written atomically as a table of
    ``info``'s objects, grid and world with their forces and heights."""
    images = [readout.apply(a) for a in sim]
    for name, a in zip(info.objects, images, strict=True):
        if (i := bad_pressure(a)) is not None:
            raise HamError(f"the fitted read-out gives {name} a pressure of {float(a[i]):g} at "
                           f"{i}; accepted: pressures in [0, {MAX_PRESSURE:g}] (recorded "
                           "glances in a smaller unit)")  # fmt: skip
    world = WorldConfig.from_dict(info.world)
    layout = None
    if info.format_version != FORMAT_VERSION:
        layout = (tuple(info.pose_dims), tuple(info.grid_shape), info.compression)

    def write(tmp: Path) -> None:
        with h5py.File(tmp, "w") as g:
            _write_images(g, info.objects, images, info.grid, world, simulator, source,
                          command, heights, layout, forces)  # fmt: skip

    return atomic_write(out, write, what="glance table")


def describe(readout: Readout) -> str:
    """One line on a fitted read-out (what the CLI prints)."""
    k = readout.kernel.shape[0]
    held_out = ""
    if readout.r2_held_out is not None:
        held_out = f" ({readout.r2_held_out:.3f} held out)"
    return (f"a {k} x {k} read-out fitted to {readout.glances} recorded glances explains "
            f"{readout.r2:.3f} of their variance{held_out}")  # fmt: skip


__all__ = ["Readout", "calibrate_table", "carry_readout", "check_kernel", "describe", "fit_readout"]
