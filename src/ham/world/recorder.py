"""Recording glances from outside (beyond the paper): a real pad's, a robot's, another
simulator's, over a grid of poses, into the ``.npz`` that :func:`ham.world.table.import_recorded`
(``ham table import-recorded``) turns into a glance table.

The paper recorded its data set once in Gazebo; a real pad records one glance at a time, slowly,
and may stop (a crash, an object to swap, the end of the day). :func:`record_glances` asks a
callable for the glance of each object at each grid pose, in the order of the table (object by
object, the last pose dim fastest), keeps what it has in ``OUT.partial.npz`` (written atomically
every ``save_every`` glances and when it stops, by an error or Ctrl-C), resumes from it, and writes
``OUT`` only when every glance is in::

    from ham.world.recorder import record_glances

    def glance(name, q):            # q: the normalized pose, one value per pose dim in [-1, 1]
        robot.place(name)           # your arm: move, press until 2 N, read the pad
        return robot.press(q)       # an (N, N) image of pressures >= 0 (any unit)

    record_glances(glance, ["cup", "ball"], 5, "cups.npz")   # 2 x 25 glances
    # then: ham table import-recorded cups.npz --out cups.h5
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from ham.errors import HamError, checked_arguments
from ham.world.files import atomic_write, check_output
from ham.world.glance import check_pose_dims
from ham.world.sensor import MAX_PRESSURE
from ham.world.table import bad_pressure, grid_shape_for, grid_values

#: the keys of a partial recording beside the objects' arrays
_DONE, _SPEC = "__done__", "__spec__"


@checked_arguments
def record_glances(
    glance: Callable[[str, np.ndarray], object],
    objects: Sequence[str],
    grid: int | Sequence[int] | str,
    out: str | os.PathLike,
    *,
    pose_dims: str | Sequence[str] = ("x", "phi"),
    heights: bool = False,
    save_every: int = 100,
    progress: bool = True,
) -> Path:
    """Record ``glance(name, q)`` for each object of ``objects`` at each point of the grid
    (``grid`` points per pose dim, one integer or one per dim, each axis
    ``numpy.linspace(-1, 1, G)``: the poses the agent asks for) into the ``.npz`` file ``out``:
    one ``(G_1, .., G_k, N, N)`` array per object, and with ``heights`` its ``NAME.height``
    ``(G_1, .., G_k)``, as :func:`ham.world.table.import_recorded` reads them.

    ``glance`` returns the ``N x N`` image (pressures >= 0, finite; the first glance fixes
    ``N``), or with ``heights`` a pair ``(image, height)`` (the contact height in m). A bad glance
    stops the recording with one line naming the object and the pose; what was recorded before
    it is kept in ``OUT.partial.npz``, as it is on any error or interrupt, and a call with the same
    objects, grid and pose dims resumes there (another is refused). A finished recording keeps
    what it recorded (``__spec__``): the same call again returns it without a glance, another
    records anew over it. Each save writes the whole recording so far (a robot's few thousand
    glances: megabytes); for a recording of tens of thousands, raise ``save_every``. Returns
    ``out``."""
    out = check_output(out, (".npz",), what="recorded glances")
    dims = check_pose_dims(pose_dims, "pose_dims")
    if not callable(glance):
        raise HamError(f"glance = {glance!r}; accepted: a callable glance(name, q) -> image")
    names = list(objects) if isinstance(objects, (list, tuple)) else []
    if not names or not all(isinstance(n, str) and n and not n.endswith(".height")
                            and not n.startswith("__") for n in names):  # fmt: skip
        raise HamError(f"objects = {objects!r}; accepted: a list of one or more names (not "
                       "ending in '.height', not starting with '__')")  # fmt: skip
    if len(set(names)) != len(names):
        raise HamError(f"objects = {names}: a name twice; accepted: each object once")
    if isinstance(grid, (list, tuple)):  # NumPy integers from a user's arange are integers too
        grid = [int(g) if isinstance(g, np.integer) else g for g in grid]
    shape = grid_shape_for(grid, dims)
    if not (isinstance(save_every, int) and not isinstance(save_every, bool) and save_every >= 1):
        raise HamError(f"save_every = {save_every!r}; accepted: an integer >= 1 (glances between "
                       "saves)")  # fmt: skip
    if not isinstance(heights, bool):
        raise HamError(f"heights = {heights!r}; accepted: true or false")
    spec = json.dumps({"objects": names, "grid": list(shape), "pose_dims": list(dims),
                       "heights": heights})  # fmt: skip
    if _recorded_spec(out) == spec:  # recorded already: a rerun asks the robot nothing
        return out
    partial = out.with_name(out.name.removesuffix(".npz") + ".partial.npz")
    poses = int(np.prod(shape))
    state = _resume(partial, spec, len(names), poses)
    values = [grid_values(g) for g in shape]
    total = len(names) * poses
    new = 0  # glances recorded since the last save

    def save() -> None:
        atomic_write(partial, lambda tmp: _save(tmp, names, state, spec, heights, shape),
                     what="partial recording")  # fmt: skip

    bar = tqdm(total=total, initial=int(state["done"].sum()), desc="recording glances",
               unit="glance", disable=not progress)  # fmt: skip
    try:
        for oi, name in enumerate(names):
            for p in np.flatnonzero(~state["done"][oi]):
                idx = np.unravel_index(p, shape)
                q = np.array([v[i] for v, i in zip(values, idx, strict=True)])
                image, height = _checked(glance(name, q.copy()), name, q, dims, heights, state)
                state["images"][oi, p] = image
                if heights:
                    state["heights"][oi, p] = height
                state["done"][oi, p] = True
                new += 1
                bar.update(1)
                if new >= save_every:
                    save()
                    new = 0
    except BaseException:  # an error, a bad glance, Ctrl-C: keep what was recorded to resume
        if new:  # (atomic: an interrupt during the save leaves the last partial file whole)
            save()
        raise
    finally:
        bar.close()

    def write(tmp: Path) -> None:
        arrays = {n: state["images"][i].reshape(*shape, *state["images"].shape[2:])
                  for i, n in enumerate(names)}  # fmt: skip
        arrays[_SPEC] = np.array(spec)  # what was recorded (import_recorded skips "__" names)
        if heights:
            arrays |= {f"{n}.height": state["heights"][i].reshape(shape)
                       for i, n in enumerate(names)}  # fmt: skip
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)

    atomic_write(out, write, what="recorded glances")
    partial.unlink(missing_ok=True)
    return out


def _checked(got, name: str, q: np.ndarray, dims, heights: bool, state: dict):
    """The glance's image (and height), checked; the first one fixes the pad's size."""
    at = f"glance({name!r}, q = [{', '.join(f'{v:g}' for v in q)}] ({','.join(dims)}))"
    height = math.nan
    if heights:
        if not (isinstance(got, tuple) and len(got) == 2):
            raise HamError(f"{at} returned {type(got).__name__}; accepted: a pair (image, "
                           "height) with heights = True")  # fmt: skip
        got, given = got
        try:
            height = float(given)
        except (TypeError, ValueError):
            height = math.nan
        if not math.isfinite(height):
            raise HamError(f"{at} returned height {given!r}; accepted: a finite height (m)")
    try:
        image = np.asarray(got, dtype=np.float32)
    except (TypeError, ValueError):
        raise HamError(f"{at} returned {type(got).__name__}; accepted: an (N, N) image of "
                       "pressures") from None  # fmt: skip
    n = state["taxels"]
    if image.ndim != 2 or image.shape[0] != image.shape[1] or image.shape[0] < 1:
        raise HamError(f"{at} returned an image of shape {image.shape}; accepted: (N, N)")
    if n is not None and image.shape != (n, n):
        raise HamError(f"{at} returned an image of shape {image.shape}; accepted: ({n}, {n}), "
                       "the pad's earlier glances")  # fmt: skip
    bad = bad_pressure(image)
    if bad is not None:
        raise HamError(f"{at} returned {float(image[bad])} at taxel {bad}; accepted: pressures "
                       f"in [0, {MAX_PRESSURE:g}]")  # fmt: skip
    if n is None:  # the first glance: the pad's size, the arrays
        state["taxels"] = image.shape[0]
        k, p = state["done"].shape
        state["images"] = np.zeros((k, p, *image.shape), np.float32)
    return image, height


def _recorded_spec(out: Path) -> str | None:
    """The spec a finished recording at ``out`` was made with (``None``: no such file)."""
    if not out.is_file():
        return None
    try:
        with np.load(out, allow_pickle=False) as f:
            return str(f[_SPEC]) if _SPEC in f.files else None
    except (OSError, ValueError, EOFError):
        return None  # not a recording of ours: written over, as any output file


def _resume(partial: Path, spec: str, n_objects: int, poses: int) -> dict:
    """The recording so far: from ``partial`` when it is one of the same spec, else empty."""
    state = {"done": np.zeros((n_objects, poses), bool), "images": None, "taxels": None,
             "heights": np.full((n_objects, poses), np.nan, np.float32)}  # fmt: skip
    if not partial.exists():
        return state
    try:
        with np.load(partial, allow_pickle=False) as f:
            stored = {k: f[k] for k in f.files}
    except (OSError, ValueError, EOFError) as exc:
        raise HamError(f"cannot read the partial recording {str(partial)!r}: {exc}; delete it "
                       "to start over") from None  # fmt: skip
    if str(stored.get(_SPEC)) != spec:
        raise HamError(f"{str(partial)!r} is a partial recording of other objects, grid or pose "
                       "dims; accepted: the same call to resume it, or delete it to start over")  # fmt: skip
    names = json.loads(spec)["objects"]
    try:
        done = stored[_DONE].astype(bool).reshape(n_objects, poses)
        images = np.stack([stored[n] for n in names])
        images = images.reshape(n_objects, poses, *images.shape[-2:]).astype(np.float32)
        if json.loads(spec)["heights"]:
            stack = np.stack([stored[f"{n}.height"] for n in names])
            state["heights"] = stack.reshape(n_objects, poses).astype(np.float32)
    except (KeyError, ValueError) as exc:  # a file changed since it was saved
        raise HamError(f"the partial recording {str(partial)!r} is incomplete ({exc}); delete it "
                       "to start over") from None  # fmt: skip
    state.update(done=done, images=images, taxels=images.shape[-1])
    return state


def _save(tmp: Path, names, state: dict, spec: str, heights: bool, shape) -> None:
    arrays = {_DONE: state["done"], _SPEC: np.array(spec)}
    for i, n in enumerate(names):
        arrays[n] = state["images"][i]
        if heights:
            arrays[f"{n}.height"] = state["heights"][i]
    with open(tmp, "wb") as f:
        np.savez(f, **arrays)
