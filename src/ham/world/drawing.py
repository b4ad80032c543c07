"""Pictures of the world: object profiles, a glance (pad over the profile + its image), tables.

All functions write PNG files with matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ham.world.files import atomic_write, check_output  # noqa: E402
from ham.world.objects import HapticObject  # noqa: E402


def save_figure(
    fig, out: str | os.PathLike, *, dpi: int = 110, tight: bool = True, what: str = "picture"
) -> Path:
    """``fig`` as the PNG ``out`` (path checked, written atomically: no partial file), then
    closed; ``tight``: cropped to its content (one more draw of the figure: seconds for many 3-D
    panels, whose layout is fixed instead)."""
    bbox = "tight" if tight else None
    try:
        out = check_output(out, (".png",), what=what)
        return atomic_write(
            out, lambda tmp: fig.savefig(tmp, dpi=dpi, bbox_inches=bbox, format="png"), what=what
        )
    finally:
        plt.close(fig)


def _solid(ax, obj: HapticObject, color: str = "#b08850") -> None:
    top = obj.outline()
    half = 0.5 * obj.width
    poly = np.vstack([[-half, 0.0], top, [half, 0.0]]) * 100  # cm
    ax.fill(poly[:, 0], poly[:, 1], color=color, alpha=0.85, lw=1.2, ec="k")


def draw_objects(objs: list[HapticObject], out: str | os.PathLike) -> Path:
    """Side profiles (x-z cross-sections) of ``objs``, one panel each, with ids and names."""
    n = len(objs)
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.0 * cols, 2.3 * rows), squeeze=False)
    from ham.world.objects import object_id

    reach = max(6.0, 50 * max(o.width for o in objs) + 1.5)  # cm: 6 for the 9 cm blocks
    for ax, obj in zip(axes.flat, objs, strict=False):
        ax.axhline(0, color="0.4", lw=2)
        _solid(ax, obj)
        ax.set_title(f"{object_id(obj.name)}: {obj.name}", fontsize=10)
        ax.set_xlim(-reach, reach)
        ax.set_ylim(-0.5, 6)
        ax.set_aspect("equal")
        ax.set_xlabel("x (cm)")
    for ax in axes.flat[n:]:
        ax.axis("off")
    axes[0, 0].set_ylabel("z (cm)")
    fig.suptitle("Object side profiles (extruded along y)", fontsize=11)
    return save_figure(fig, out)


def draw_glance(
    obj: HapticObject, result: dict, sensor_size: float, out: str | os.PathLike
) -> Path:
    """The pad at the end of a glance over the object's profile, beside its N x N image (any N).

    ``result`` is :meth:`ham.world.glance.GlanceResult.to_json` of one glance.
    """
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(8.4, 3.4), gridspec_kw={"width_ratios": [1.5, 1]})
    a0.axhline(0, color="0.4", lw=2)
    _solid(a0, obj)
    x, z, phi = result["x"], result["z"], result["phi"]
    half = 0.5 * sensor_size
    t = np.array([math.cos(phi), -math.sin(phi)])
    up = np.array([math.sin(phi), math.cos(phi)])
    c = np.array([x, z])
    face = np.array([c - half * t, c + half * t])
    body = np.array(
        [c - half * t, c + half * t, c + half * t + 0.012 * up, c - half * t + 0.012 * up]
    )
    a0.fill(*(body * 100).T, color="#c0392b", alpha=0.8, ec="k", lw=1)
    a0.plot(*(face * 100).T, color="k", lw=3)
    a0.set_xlim(-9, 9)
    a0.set_ylim(-0.5, 12)
    a0.set_aspect("equal")
    a0.set_xlabel("x (cm)")
    a0.set_ylabel("z (cm)")
    a0.set_title(
        f"{obj.name}: x = {x * 100:.1f} cm, phi = {math.degrees(phi):.0f} deg\n"
        f"F = {result['force']:.2f} N, z = {z * 100:.2f} cm"
        + (" (blocked)" if result.get("blocked") else ""),
        fontsize=9,
    )
    img = np.asarray(result["pressure"])
    im = a1.imshow(img, cmap="inferno", origin="upper", vmin=0)
    a1.set_title("pressure (Pa); rows: y, columns: pad u", fontsize=9)
    a1.set_xlabel("column (u, -x ... +x)")
    a1.set_ylabel("row (y)")
    fig.colorbar(im, ax=a1, fraction=0.046)
    return save_figure(fig, out)


def draw_table_grid(
    pressure: np.ndarray, q: np.ndarray, title: str, out: str | os.PathLike
) -> Path:
    """A picture grid of tactile images: ``pressure`` (n_x, n_phi, N, N) at poses ``q`` (any N)."""
    nx, nphi = pressure.shape[:2]
    fig, axes = plt.subplots(nphi, nx, figsize=(1.3 * nx, 1.3 * nphi), squeeze=False)
    vmax = float(pressure.max()) or 1.0
    for i in range(nx):
        for j in range(nphi):
            ax = axes[nphi - 1 - j, i]
            ax.imshow(pressure[i, j], cmap="inferno", vmin=0, vmax=vmax)
            ax.set_xticks([])
            ax.set_yticks([])
            if j == 0:
                ax.set_xlabel(f"q_x={q[0][i]:+.2f}", fontsize=7)
            if i == 0:
                ax.set_ylabel(f"q_phi={q[1][j]:+.2f}", fontsize=7)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, out)


def draw_objects_3d(
    objs: list[HapticObject], out: str | os.PathLike, title: str | None = None
) -> Path:
    """Each object's top ``h(x, y)`` as a shaded 3-D surface (one panel each, ids and names),
    with its walls down to the table; all panels share one scale (cm)."""
    from matplotlib.colors import LightSource
    from matplotlib.ticker import MaxNLocator

    from ham.world.objects import object_id

    n = len(objs)
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    fig = plt.figure(figsize=(3.2 * cols, 2.9 * rows))
    half = 50 * max(max(o.width, o.depth) for o in objs)  # cm
    top = 100 * max(o.height for o in objs)
    light = LightSource(azdeg=315, altdeg=45)
    for k, obj in enumerate(objs):
        ax = fig.add_subplot(rows, cols, k + 1, projection="3d")
        # 2 mm samples plus one just beyond each side, where the table (0) makes the walls; at
        # most 61 a side, 25 in a figure of more than 12 panels (rendering time grows with both).
        most = 61 if n <= 12 else 25
        nx = min(most, max(2, round(obj.width / 0.002) + 1))
        ny = min(most, max(2, round(obj.depth / 0.002) + 1))
        hw, hd = 0.5 * obj.width, 0.5 * obj.depth
        xs = np.concatenate([[-hw - 1e-9], np.linspace(-hw, hw, nx), [hw + 1e-9]])
        ys = np.concatenate([[-hd - 1e-9], np.linspace(-hd, hd, ny), [hd + 1e-9]])
        gx, gy = np.meshgrid(xs, ys)
        z = obj.surface(gx, gy) * 100
        rgb = light.shade(z, cmap=plt.cm.copper, vert_exag=3, blend_mode="soft", vmin=0, vmax=top)
        ax.plot_surface(
            gx * 100, gy * 100, z, facecolors=rgb, rstride=1, cstride=1, linewidth=0,
            antialiased=False, shade=False,
        )  # fmt: skip
        ax.set_xlim(-half, half)
        ax.set_ylim(-half, half)
        ax.set_zlim(0, top)
        ax.set_box_aspect((1, 1, max(top / (2 * half), 0.15)))
        ax.view_init(elev=35, azim=-60)
        ax.set_title(f"{object_id(obj.name)}: {obj.name}", fontsize=9)
        ax.tick_params(labelsize=6, pad=0)
        ax.zaxis.set_major_locator(MaxNLocator(3))
        ax.set_xlabel("x (cm)", fontsize=7, labelpad=-4)
        ax.set_ylabel("y (cm)", fontsize=7, labelpad=-4)
    # fixed margins (inches over the figure's height): tight_layout and a tight crop measure
    # every 3-D axis (14 of 21 s for the 41 objects of `ham objects --out`)
    inch = 1 / fig.get_figheight()
    fig.suptitle(title or "Objects: top h(x, y) (cm)", fontsize=11, y=1 - 0.12 * inch)
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.15 * inch, top=1 - 0.75 * inch,
                        wspace=0.05, hspace=0.15)  # fmt: skip
    return save_figure(fig, out, tight=False)
