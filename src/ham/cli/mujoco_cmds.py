"""``ham render``: draw a MuJoCo glance with the engine's offscreen renderer.

The scene is the MuJoCo simulator's (section "Scenario and Experimental Setup": the objects in a row
on the table, the Myrmex pad held at its pose); the pad is shown where the force-controlled glance
stopped, beside the tactile image it read. Offscreen OpenGL needs EGL or OSMesa from the system's
packages (``libegl1`` or ``libosmesa6``); ``MUJOCO_GL`` picks one (``egl`` is tried when no display is
set). Without either, the command says so and exits non-zero.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from ham.cli.options import add_objects_file_option, objects_from_args
from ham.errors import HamError
from ham.world.sensor import READOUTS

GL_HELP = (
    "MuJoCo's offscreen renderer needs an OpenGL backend: install EGL (Debian/Ubuntu: "
    "apt-get install libegl1) or OSMesa (apt-get install libosmesa6) and set MUJOCO_GL=egl or "
    "MUJOCO_GL=osmesa"
)


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Add ``render`` to the ``ham`` CLI's subparsers."""
    p = subparsers.add_parser(
        "render",
        help="draw one MuJoCo glance (needs EGL or OSMesa)",
        description="Perform one MuJoCo glance and draw the scene with the pad at its stop height, "
        "beside the tactile image.",
    )
    p.add_argument("--object", required=True, help="object id or name within --objects")
    p.add_argument("--x", type=float, required=True, help="normalized position q_x in [-1, 1]")
    p.add_argument("--phi", type=float, required=True, help="normalized angle q_phi in [-1, 1]")
    p.add_argument("--y", type=float, default=None,
                   help="normalized position q_y in [-1, 1] (the extended glance; default 0)")  # fmt: skip
    p.add_argument("--phi-y", type=float, default=None, dest="phi_y",
                   help="normalized tilt q_phi_y about x in [-1, 1] (default 0)")  # fmt: skip
    p.add_argument("--out", required=True, help="output PNG path")
    p.add_argument("--objects", default=None, help="object set (default: paper; with "
                   "--objects-file: the file's objects)")  # fmt: skip
    add_objects_file_option(p)
    p.add_argument("--sensor", default="taxels", choices=READOUTS, help="read-out")
    p.add_argument("--width", type=int, default=960, help="image width in pixels (64..4096)")
    p.add_argument("--height", type=int, default=720, help="image height in pixels (64..4096)")
    p.set_defaults(func=cmd_render)


def _check_size(name: str, value: int) -> int:
    if not 64 <= value <= 4096:
        raise HamError(f"--{name} = {value}; accepted: 64..4096 pixels")
    return value


def cmd_render(args: argparse.Namespace) -> int:
    """Entry point of ``ham render``; returns the exit code."""
    width = _check_size("width", args.width)
    height = _check_size("height", args.height)
    from ham.world.files import check_output

    out = check_output(args.out, (".png",))
    objects, _ = objects_from_args(args)  # registers --objects-file's objects
    render_glance(
        objects,
        args.object,
        args.x,
        args.phi,
        out,
        width=width,
        height=height,
        readout=args.sensor,
        q_y=args.y,
        q_phi_y=args.phi_y,
    )
    print(f"wrote {out}")
    return 0


def _select_gl_backend() -> str:
    """Choose MUJOCO_GL before MuJoCo is imported: the user's choice, else EGL without a display."""
    if (
        "MUJOCO_GL" not in os.environ
        and "mujoco" not in sys.modules
        and not os.environ.get("DISPLAY")
    ):
        os.environ["MUJOCO_GL"] = "egl"
    return os.environ.get("MUJOCO_GL", "glfw")


def render_glance(
    object_set: str,
    obj: str,
    q_x: float,
    q_phi: float,
    out: Path,
    *,
    width: int = 960,
    height: int = 720,
    readout: str = "taxels",
    q_y: float | None = None,
    q_phi_y: float | None = None,
) -> Path:
    """Glance once with MuJoCo and write a PNG: the scene (left) and the tactile image (right).

    ``q_y``, ``q_phi_y``: the extended glance's pose (``None``: the paper's glance)."""
    backend = _select_gl_backend()
    try:
        import mujoco
    except Exception as exc:  # a broken GL library can fail the import itself
        raise HamError(
            f"MuJoCo could not load with MUJOCO_GL={backend}: {exc}. {GL_HELP}"
        ) from None
    from ham.world import objects as _objects
    from ham.world.mujoco_sim import STATUS_NAMES, MujocoSimulator

    objs = _objects.resolve_set(object_set)
    target = _objects.get(obj)
    if target not in objs:
        names = [o.name for o in objs]
        raise HamError(f"--object {obj!r} is not in the object set {object_set!r}: {names}")
    oid = objs.index(target)
    sim = MujocoSimulator(objs, readout=readout, threads=1)
    m, d, res = sim.settled_scene(oid, q_x, q_phi, q_y, q_phi_y)
    try:
        renderer = mujoco.Renderer(m, height, width)
    except Exception as exc:
        raise HamError(
            f"no OpenGL context for offscreen rendering (MUJOCO_GL={backend}): {exc}. {GL_HELP}"
        ) from None
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    pad = m.body("pad").id
    cam.lookat[:] = d.xpos[pad] - [0.0, 0.0, 0.02]
    cam.distance = 0.3
    cam.azimuth = 90.0
    cam.elevation = -12.0
    try:
        renderer.update_scene(d, camera=cam)
        pixels = renderer.render()
    finally:
        renderer.close()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a0, a1) = plt.subplots(
        1, 2, figsize=(width / 100 * 1.5, height / 100), gridspec_kw={"width_ratios": [2, 1]}
    )
    a0.imshow(pixels)
    a0.set_axis_off()
    status = STATUS_NAMES[int(res.info["status"][0])]
    pose = f"q = ({q_x:+.2f}, {q_phi:+.2f}), x = {float(res.x[0]) * 1e3:.1f} mm, "
    pose += f"phi = {float(res.phi[0]):.3f} rad"
    if q_y is not None or q_phi_y is not None:
        pose += f", y = {float(res.y[0]) * 1e3:.1f} mm, phi_y = {float(res.phi_y[0]):.3f} rad"
    a0.set_title(
        f"{target.name}: {pose}; z = {float(res.z[0]) * 1e3:.2f} mm, "
        f"F = {float(res.force[0]):.2f} N ({status})",
        fontsize=9,
    )
    im = a1.imshow(res.pressure[0].numpy(), cmap="viridis", origin="lower")
    a1.set_title(f"{readout} read-out (Pa); rows y, columns u", fontsize=9)
    fig.colorbar(im, ax=a1, fraction=0.046)
    from ham.world.drawing import save_figure

    fig.tight_layout()
    return save_figure(fig, out, dpi=100, tight=False)


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m ham.cli.mujoco_cmds render ...``) until ``ham`` wires it in."""
    parser = argparse.ArgumentParser(prog="ham-mujoco")
    add_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except HamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
