"""Cross-check the MuJoCo glance against the fast foam model; write docs/crosscheck.md and its pictures.

    .venv/bin/python -m ham.experiments.crosscheck            # writes docs/crosscheck.md, docs/img/crosscheck_*.png
    .venv/bin/python -m ham.experiments.crosscheck2d          # the curvature2d report (issue 12)

Every number and picture in the report comes from this run (section "Scenario and Experimental
Setup" of the paper: the glance, the Myrmex pad and its Gazebo plugin).
"""

from __future__ import annotations

import argparse
import math
import os
import time
from dataclasses import asdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from ham.world.drawing import save_figure  # noqa: E402
from ham.world.files import write_text  # noqa: E402
from ham.world.glance import FastSimulator  # noqa: E402
from ham.world.mujoco_sim import (  # noqa: E402
    BLOCKED,
    SETTLED,
    STATUS_NAMES,
    MujocoSimulator,
    calibrate_foam_stiffness,
    contact_centroid,
    image_correlation,
)
from ham.world.objects import resolve_set  # noqa: E402
from ham.world.sensor import SensorConfig  # noqa: E402

ROOT = Path.cwd()  # run from the repository root: writes docs/crosscheck.md and docs/img
PHI_MAX = math.pi / 2
#: The dense scan at |phi| <= 0.5 rad: q_x values x phi values per object.
DENSE = (161, 7)
#: Poses of the picture grids: (q_x, phi in rad).
FIGURE_POSES = [(0.0, 0.0), (1.0, 0.0), (0.5, 0.3), (-0.5, -0.3), (0.9, 0.5), (-0.2, 1.2)]


#: The paper report's pointer to the curvature2d report (issue 12), which has its own run.
HEIGHT_FIELD_SECTION = (
    "The extended glance of issue 12 (pose `(x, y, phi, phi_y)`, objects whose top varies in "
    "x and y) is cross-checked on the `curvature2d` set in its own report, "
    "[crosscheck_curvature2d.md](crosscheck_curvature2d.md), written by "
    "`.venv/bin/python -m ham.experiments.crosscheck2d` (about 30 s on 2 "
    "cores). There MuJoCo builds each object as a height field (`hfield`) and keeps one contact "
    "per taxel; the paper's objects and poses above are glanced exactly as before.\n"
)


def grid(n_x: int, n_phi: int, phi_limit: float):
    qx = np.linspace(-1.0, 1.0, n_x)
    qp = np.linspace(-phi_limit, phi_limit, n_phi) / PHI_MAX
    QX, QP = np.meshgrid(qx, qp)
    return QX.ravel(), QP.ravel()


def run(sim, fast, oid, qx, qp):
    ids = np.full(len(qx), oid)
    return sim.glance(ids, qx, qp), fast.glance(ids, qx, qp)


def draw_grid(
    path: Path, title: str, cols: list[tuple[str, list[np.ndarray]]], row_names: list[str]
):
    """A picture grid: one column per pose, one row per simulator/read-out."""
    n_rows, n_cols = len(row_names), len(cols)
    fig, axes = plt.subplots(
        n_rows, n_cols, figsize=(2.1 * n_cols, 2.25 * n_rows + 0.4), squeeze=False
    )
    for j, (label, images) in enumerate(cols):
        for i, img in enumerate(images):
            ax = axes[i, j]
            vmax = max(float(img.max()), 1e-9)
            ax.imshow(img, cmap="viridis", origin="lower", vmin=0, vmax=vmax)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(label, fontsize=7)
            if j == 0:
                ax.set_ylabel(row_names[i], fontsize=8)
            ax.text(0.5, -1.0, f"max {vmax:.0f} Pa", fontsize=6, color="w", va="top")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=90, tight=False)


def rim_share(img) -> float:
    """Share of an image's force in its two outermost columns (the pad's rim)."""
    cols = np.asarray(img, dtype=np.float64).sum(0)
    return float((cols[0] + cols[-1]) / max(cols.sum(), 1e-30))


def fmt_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", default=str(ROOT / "docs" / "crosscheck.md"))
    ap.add_argument("--threads", type=int, default=None, help="MuJoCo threads (default: all cores)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    out = Path(args.out)
    img_dir = out.parent / "img"
    img_dir.mkdir(parents=True, exist_ok=True)
    objs = resolve_set("paper")

    cal = calibrate_foam_stiffness()
    sensor = SensorConfig(foam_stiffness=cal["foam_stiffness"])
    mj = MujocoSimulator(objs, sensor, threads=args.threads)
    gz = MujocoSimulator(objs, sensor, threads=args.threads, readout="gazebo")
    fast = FastSimulator(objs, sensor)
    cfg = mj.config

    # ---------------------------------------------------------------- |phi| <= 0.5 rad
    qx, qp = grid(21, 11, 0.5)
    main_rows, worst = [], []
    n_glances, t_mj = 0, 0.0
    for oid, obj in enumerate(objs):
        t0 = time.perf_counter()
        r, f = run(mj, fast, oid, qx, qp)
        t_mj += time.perf_counter() - t0
        n_glances += len(qx)
        corr = image_correlation(r.pressure, f.pressure)
        dz = (r.z - f.z).numpy() * 1e3
        st = r.info["status"].numpy()
        pooled = np.corrcoef(r.pressure.double().flatten(), f.pressure.double().flatten())[0, 1]
        main_rows.append(
            [
                obj.name,
                str(len(qx)),
                f"{corr.mean():.3f}",
                f"{np.median(corr):.3f}",
                f"{corr.min():.3f}",
                f"{np.mean(corr >= 0.85):.1%}",
                f"{pooled:.3f}",
                f"{np.abs(dz).max():.2f}",
                f"{np.abs(dz).mean():.2f}",
                f"{np.mean(st == SETTLED):.1%}",
            ]
        )
        for i in np.argsort(corr)[:2]:
            worst.append(
                (
                    corr[i],
                    dz[i],
                    obj.name,
                    oid,
                    qx[i],
                    qp[i],
                    r.pressure[i].numpy(),
                    f.pressure[i].numpy(),
                )
            )

    # ---------------------------------------------------------------- how fine is either model?
    # A dense scan at |phi| <= 0.5 rad: MuJoCo against the fast model, and the fast model (4
    # read-out points per cell, its default) against itself with 64 points per cell.
    fine = FastSimulator(objs, SensorConfig(foam_stiffness=cal["foam_stiffness"], supersample=64))
    qx3, qp3 = grid(DENSE[0], DENSE[1], 0.5)
    res_rows, self_rows, other_poses, self_worst = [], [], [], []
    miss_mj, miss_self = [], []  # per object: share of poses below 0.85
    for oid, obj in enumerate(objs):
        t0 = time.perf_counter()
        r, f = run(mj, fast, oid, qx3, qp3)
        t_mj += time.perf_counter() - t0
        n_glances += len(qx3)
        g = fine.glance(np.full(len(qx3), oid), qx3, qp3)
        corr = image_correlation(r.pressure, f.pressure)
        shift = np.abs(contact_centroid(r.pressure) - contact_centroid(f.pressure))
        low = corr < 0.85
        near = low & (shift <= 1.0 + 1e-9)
        for i in np.where(low & ~near)[0]:
            other_poses.append(
                (
                    obj.name,
                    qx3[i],
                    qp3[i] * PHI_MAX,
                    corr[i],
                    shift[i],
                    rim_share(f.pressure[i]),
                    rim_share(r.pressure[i]),
                )
            )
        c_self = image_correlation(f.pressure, g.pressure)
        s_self = np.abs(contact_centroid(f.pressure) - contact_centroid(g.pressure))
        low_self = c_self < 0.85
        c_fine = image_correlation(r.pressure, g.pressure)
        miss_mj.append(float(low.mean()))
        miss_self.append(float(low_self.mean()))
        res_rows.append(
            [
                obj.name,
                str(len(qx3)),
                f"{np.mean(~low):.1%}",
                str(int(low.sum())),
                str(int(near.sum())),
                str(int((low & ~near).sum())),
                f"{np.mean(c_fine >= 0.85):.1%}",
            ]
        )
        self_rows.append(
            [
                obj.name,
                f"{np.mean(~low_self):.1%}",
                str(int(low_self.sum())),
                f"{c_self.min():.2f}",
                f"{s_self[low_self].max():.2f}" if low_self.any() else "-",
                f"{np.abs((f.z - g.z).numpy()).max() * 1e3:.2f}",
            ]
        )
        for i in np.argsort(c_self)[:1]:
            self_worst.append(
                (
                    f"{obj.name} q_x={qx3[i]:+.3f}\nphi={qp3[i] * PHI_MAX:+.2f}: "
                    f"corr {c_self[i]:.2f}\ncentroids {s_self[i]:.2f} apart",
                    [f.pressure[i].numpy(), g.pressure[i].numpy(), r.pressure[i].numpy()],
                )
            )
    self_path = img_dir / "crosscheck_resolution.png"
    draw_grid(
        self_path,
        "The fast model against itself: 4 vs 64 read-out points per cell (and MuJoCo)",
        self_worst,
        ["fast, 4 points", "fast, 64 points", "MuJoCo taxels"],
    )

    # ---------------------------------------------------------------- full range, by |phi| band
    qx2, qp2 = grid(21, 41, PHI_MAX)
    bands = [(0.0, 0.5), (0.5, 1.0), (1.0, 1.3), (1.3, PHI_MAX + 1e-9)]
    acc = {
        b: {
            "corr": [],
            "dz": [],
            "agree": [],
            "mjb": [],
            "fb": [],
            "fail": [],
            "gzb": [],
            "gzagree": [],
        }
        for b in bands
    }
    for oid in range(len(objs)):
        t0 = time.perf_counter()
        r, f = run(mj, fast, oid, qx2, qp2)
        t_mj += time.perf_counter() - t0
        n_glances += len(qx2)
        corr = image_correlation(r.pressure, f.pressure)
        st = r.info["status"].numpy()
        mjb, fb = st != SETTLED, f.blocked.numpy()
        gzb = gz.glance(np.full(len(qx2), oid), qx2, qp2).info["status"].numpy() != SETTLED
        dz = np.abs((r.z - f.z).numpy()) * 1e3
        phi = np.abs(r.phi.numpy())
        for b in bands:
            sel = (phi >= b[0]) & (phi < b[1])
            both = sel & ~mjb & ~fb
            acc[b]["corr"] += list(corr[both])
            acc[b]["dz"] += list(dz[both])
            acc[b]["agree"] += list((mjb == fb)[sel])
            acc[b]["mjb"] += list(mjb[sel])
            acc[b]["fb"] += list(fb[sel])
            acc[b]["fail"] += list(st[sel] > BLOCKED)
            acc[b]["gzb"] += list(gzb[sel])
            acc[b]["gzagree"] += list((gzb == fb)[sel])
    band_rows = []
    for b in bands:
        a = acc[b]
        c = np.array(a["corr"])
        band_rows.append(
            [
                f"{b[0]:.1f} - {min(b[1], PHI_MAX):.2f}",
                str(len(a["agree"])),
                f"{np.mean(a['fb']):.1%}",
                f"{np.mean(a['mjb']):.1%}",
                f"{np.mean(a['agree']):.1%}",
                f"{np.mean(a['fail']):.1%}",
                f"{np.mean(a['gzb']):.1%}",
                f"{np.mean(a['gzagree']):.1%}",
                f"{c.mean():.3f}" if len(c) else "-",
                f"{np.mean(c >= 0.85):.1%}" if len(c) else "-",
                f"{np.max(a['dz']):.2f}" if len(c) else "-",
            ]
        )

    # ---------------------------------------------------------------- picture grids
    figures = []
    for oid, obj in enumerate(objs):
        cols = []
        for q_x, phi in FIGURE_POSES:
            q_phi = phi / PHI_MAX
            r, f = run(mj, fast, oid, [q_x], [q_phi])
            g = gz.glance([oid], [q_x], [q_phi])
            c = float(image_correlation(r.pressure, f.pressure)[0])
            dz = (float(r.z[0]) - float(f.z[0])) * 1e3
            label = (
                f"q_x={q_x:+.1f}, phi={phi:+.1f}\ncorr {c:.2f}, dz {dz:+.2f} mm\n"
                f"mj {STATUS_NAMES[int(r.info['status'][0])]}, fast {'blocked' if bool(f.blocked[0]) else 'ok'}"
            )
            cols.append(
                (label, [r.pressure[0].numpy(), f.pressure[0].numpy(), g.pressure[0].numpy()])
            )
        path = img_dir / f"crosscheck_{obj.name}.png"
        draw_grid(
            path,
            f"{obj.name}: MuJoCo taxels / fast foam / MuJoCo gazebo read-out",
            cols,
            ["MuJoCo taxels", "fast", "gazebo"],
        )
        figures.append((obj.name, path))
    worst.sort(key=lambda w: w[0])
    cols = [
        (
            f"{w[2]} q_x={w[4]:+.2f}\nphi={w[5] * PHI_MAX:+.2f}: corr {w[0]:.2f}\ndz {w[1]:+.2f} mm",
            [w[6], w[7]],
        )
        for w in worst[:6]
    ]
    dis_path = img_dir / "crosscheck_disagreements.png"
    draw_grid(
        dis_path,
        "Lowest correlations at |phi| <= 0.5 rad (2 per object)",
        cols,
        ["MuJoCo taxels", "fast"],
    )

    # ---------------------------------------------------------------- ramp top edge: line vs blobs
    edge = []
    for name, sim in (("MuJoCo taxels", mj), ("fast", fast), ("MuJoCo gazebo", gz)):
        img = sim.glance([1], [1.0], [0.0]).pressure[0].numpy()
        edge.append((name, img))
    edge_path = img_dir / "crosscheck_ramp_edge.png"
    draw_grid(
        edge_path,
        "ramp_up, pad centred over the top edge, flat: a line, a line, two blobs",
        [(n, [im]) for n, im in edge],
        ["image"],
    )

    # ---------------------------------------------------------------- write the report
    rate = n_glances / t_mj
    rel = lambda p: os.path.relpath(p, out.parent)  # noqa: E731
    md = []
    md.append("# MuJoCo glances cross-checked against the fast foam model\n")
    md.append(
        "Generated by `.venv/bin/python -m ham.experiments.crosscheck` "
        f'(MuJoCo {mujoco.__version__}); every number and picture below comes from that run, except the section "What we tried", which says where its numbers come from.\n'
    )
    md.append("## What is compared\n")
    md.append(
        'Both simulators perform the paper\'s glance (section "Haptic Control of the Simulated Myrmex"): '
        "the pad is lowered at a fixed pose `(x, phi)` until the summed force on its 16 x 16 cells is 2 N. "
        "The **fast** model (`ham.world.glance.FastSimulator`) treats the face as a Winkler foam and solves the "
        "stop height exactly. The **MuJoCo** model (`ham.world.mujoco_sim.MujocoSimulator`) pushes a pad whose "
        "face is 16 x 16 sphere taxels (one contact each) down with a force actuator, closes the loop on "
        "the taxels' summed normal force and waits until the pad has settled. The **gazebo** read-out "
        "replaces the taxels by one box face and spreads each contact point's normal force over the "
        "taxels with a Gaussian of sigma 5 mm, like the paper's Gazebo plugin.\n"
    )
    md.append("## Calibration: the same depth on the flat box\n")
    md.append(
        f"MuJoCo's taxel contacts are linear springs of `contact_stiffness` = {cfg.contact_stiffness:g} N/m "
        f"each (pad mass {cfg.pad_mass * 1e3:.2f} g derived from it, `solref` = {cfg.taxel_solref()}, "
        f"`solimp` = {tuple(round(v, 4) for v in cfg.taxel_solimp())}, time step {cfg.timestep * 1e3:g} ms, "
        f"joint damping {cfg.joint_damping:g} N s/m). One glance at the centre of the box, flat, settled "
        f"to 1e-9 m/s: depth **{cal['depth_m'] * 1e6:.3f} um** at {cal['force_N']:.6f} N, "
        f"so the fast model's foam stiffness is 2 N / (64 cm^2 x depth) = "
        f"**{cal['foam_stiffness']:.4g} Pa/m** (`calibrate_foam_stiffness()`). All comparisons below use "
        "the fast model with this stiffness.\n"
    )
    md.append("## Cross-check at |phi| <= 0.5 rad\n")
    md.append(
        "Grid: 21 values of q_x in [-1, 1] x 11 angles in [-0.5, 0.5] rad per object. `corr` is the "
        "Pearson correlation of a MuJoCo image with the fast image at the same pose (two uniform images "
        "count as 1); `pooled` correlates all images of an object at once; `dz` is MuJoCo's stop height "
        "minus the fast model's (mm).\n"
    )
    md.append(
        fmt_table(
            [
                "object",
                "poses",
                "corr mean",
                "median",
                "min",
                "corr >= 0.85",
                "pooled",
                "max abs dz",
                "mean abs dz",
                "MuJoCo settled",
            ],
            main_rows,
        )
        + "\n"
    )
    md.append(
        "The criterion of issue 3 (images correlate at >= 0.85, heights within 2 mm) holds for every "
        "object on average and in the pooled correlation, and the height difference holds at every pose. "
        "Pose by pose, the column `corr >= 0.85` gives the share that passes. The next section shows "
        "that the rest are below the resolution of either model: the fast model misses the same "
        "criterion against itself at a finer read-out. `tests/test_mujoco.py` checks all of this on a "
        "9 x 5 subset per object.\n"
    )
    md.append("## How fine is either model?\n")
    md.append(
        f"Dense grid: {DENSE[0]} values of q_x x {DENSE[1]} angles in [-0.5, 0.5] rad per object. "
        "A pose misses when its correlation is below 0.85; the miss is *within one taxel* when the "
        "force-weighted mean columns of the two images (`ham.world.mujoco_sim.contact_centroid`) are at most "
        "one column (5 mm) apart: the same line, put in the neighbouring column.\n"
    )
    md.append("MuJoCo against the fast model (4 read-out points per cell, the default):\n")
    md.append(
        fmt_table(
            [
                "object",
                "poses",
                "corr >= 0.85",
                "misses",
                "within one taxel",
                "other",
                "MuJoCo vs fast with 64 points: corr >= 0.85",
            ],
            res_rows,
        )
        + "\n"
    )
    md.append(
        "The fast model against itself: its default read-out (4 points per cell) against the same "
        "foam read at 64 points per cell, which has converged:\n"
    )
    md.append(
        fmt_table(
            [
                "object",
                "corr >= 0.85",
                "misses",
                "min corr",
                "max centroid distance of misses (taxels)",
                "max abs dz (mm)",
            ],
            self_rows,
        )
        + "\n"
    )
    md.append(
        f"![fast against itself]({rel(self_path)})\n\n"
        "The fast model disagrees with its own finer read-out at the same kind of pose, "
        f"at {min(miss_self):.1%}-{max(miss_self):.1%} of poses per object (MuJoCo against it: "
        f"{min(miss_mj):.1%}-{max(miss_mj):.1%}): an edge within about a millimetre of a cell border. "
        "There the foam is compressed over a strip one or two millimetres wide, and whether a cell "
        "reads it depends on where its read-out points fall; with 4 points the whole strip can fall "
        "between the points of one cell and into the next. MuJoCo's sphere taxels split such an edge "
        "between the two cells by their distance to it. A correlation of 0.85 at every single pose "
        "therefore asks for more than either model resolves: the default fast model does not meet it "
        "against its own converged read-out. What the check can ask pose by pose, and what holds at "
        "every pose of the dense scan except those listed below, is that a pose either correlates at "
        ">= 0.85 or has its contact within one taxel.\n"
    )
    if other_poses:
        md.append(
            fmt_table(
                [
                    "object",
                    "q_x",
                    "phi (rad)",
                    "corr",
                    "centroid distance (taxels)",
                    "fast: force in rim columns",
                    "MuJoCo: force in rim columns",
                ],
                [
                    [n, f"{q:+.4f}", f"{ph:+.3f}", f"{c:.2f}", f"{d:.2f}", f"{a:.0%}", f"{b:.0%}"]
                    for n, q, ph, c, d, a, b in other_poses
                ],
            )
            + "\n"
        )
        md.append(
            "Where the fast image holds much of its force in a rim column that MuJoCo's leaves (almost) "
            "empty, this is the pad rim: the lowered end of the tilted pad reaches past the object, "
            "down to the table or a falling surface. The fast face is flat to its rim, so its corner is "
            "its lowest point and its outermost read-out point (1.9 mm in from the rim) presses in; "
            "MuJoCo's rim taxel is a sphere, whose lowest point at a tilt of 0.5 rad lies about half a "
            "millimetre higher than the face's corner at such a pose, so it barely touches.\n"
        )
    else:
        md.append("(No such pose in this run.)\n")
    md.append("## Over the whole range of phi\n")
    md.append(
        "Grid: 21 values of q_x x 41 angles in [-pi/2, pi/2] per object, grouped by |phi| (rad). "
        "`blocked` means the glance ended below 2 N (the housing held the pad; for MuJoCo also a step "
        "limit); `agree` is the share of poses where MuJoCo (taxels or gazebo face) and the fast model "
        "agree on whether the glance is blocked; `corr` and `max abs dz` are over poses where neither is "
        "blocked.\n"
    )
    md.append(
        fmt_table(
            [
                "abs(phi)",
                "poses",
                "fast blocked",
                "MuJoCo blocked",
                "blocked agree",
                "MuJoCo step limit",
                "gazebo blocked",
                "gazebo agree",
                "corr mean",
                "corr >= 0.85",
                "max abs dz",
            ],
            band_rows,
        )
        + "\n"
    )
    md.append("## Pictures\n")
    md.append(
        "Each column is one pose (q_x, phi in rad); rows: MuJoCo taxels, fast, MuJoCo gazebo read-out. "
        "Each image has its own colour scale (its maximum is printed in it).\n"
    )
    for name, path in figures:
        md.append(f"### {name}\n\n![{name}]({rel(path)})\n")
    md.append("### The ramp's top edge\n")
    md.append(
        f"![ramp edge]({rel(edge_path)})\n\nBoth simulators show the edge as a line across all 16 rows; the "
        "gazebo read-out shows two blobs where the edge leaves the face: MuJoCo's box-box/box-mesh "
        "collision reports two contact points there, as Gazebo's libccd did in the paper.\n"
    )
    md.append("### Where they disagree most\n")
    md.append(f"![disagreements]({rel(dis_path)})\n")
    md.append("## Why they disagree\n")
    md.append(
        "* **An edge near a cell border.** Both simulators see an edge as a line one or two columns wide, "
        "but they can put it in neighbouring columns. The fast foam compresses a strip beside the edge, "
        "on the side of the face that recedes more slowly (as wide as the compression divided by the "
        "relative slope, one or two millimetres here), and a cell reads the compression at its 4 "
        "read-out points. A MuJoCo taxel is a sphere with one contact: the edge loads the sphere(s) it "
        "presses into, by their distance to it. When the edge lies within about a millimetre of a cell "
        "border, the two can put the line one column apart: correlation down to "
        f"{min(w[0] for w in worst):.2f} (the lowest-correlation pictures above), while the heights "
        "still agree. The fast model read at 64 points per cell differs from its own 4-point read-out "
        'in the same way and about as often (section "How fine is either model?").\n'
        "* **Depth at sharp edges.** The foam carries an edge only over the narrow strip it compresses, "
        "so it sinks deeper there than a row of taxel springs, which each take a full share. MuJoCo "
        "therefore stops higher on edges, by up to the `max abs dz` of the tables; against a steeply "
        "tilted pad the foam's strip is narrowest and the difference largest. On flat contacts the two "
        "agree to micrometres, by the calibration.\n"
        "* **Steep tilts and the pad rim.** The sphere taxels of the outer columns reach "
        f"{cfg.taxel_radius * 1e3 - mj.sensor.pitch * 500:.1f} mm beyond the 8 cm face (their radius is "
        f"{cfg.taxel_radius * 1e3:g} mm, the pitch 5 mm), while the fast model's face ends exactly at the "
        "rim, where its rigid housing begins. Beyond |phi| of about 1 rad the fast pad is often held by "
        "its housing (blocked, less than 2 N), while a MuJoCo rim sphere still finds the surface and "
        "reaches 2 N: the `blocked agree` column falls there. The gazebo read-out, whose face is a box "
        "that ends at the rim, agrees far better on which glances are blocked. Concave shapes (`mhsb` "
        "set, not part of this check) show the rim effect at small tilts too, where the rim sphere rests "
        "on a trough's edge that the fast face never reaches.\n"
        "* **Gazebo read-out.** The gazebo images are not meant to agree: with few contact points an "
        "edge becomes blobs and a flat top four corner blobs, the paper's artifact.\n"
    )
    md.append("## Speed\n")
    md.append(
        f"The MuJoCo glances of this report ran at {rate:.0f} glances/s on {mj._threads} thread(s) of "
        f"{os.cpu_count()} cores (a shared machine; the tables above weight poses uniformly). "
        "`.venv/bin/python benchmarks/bench_mujoco.py` times a random sample of the full 4 x 201 x 201 "
        "grid and projects the table time.\n"
    )
    md.append("## What we tried (measured in earlier runs, not re-run by this script)\n")
    md.append(
        "On the MuJoCo side only, keeping the fast model fixed, these taxel models were tried to move "
        "the per-pose share towards every pose. Shares are of a dense scan (161 q_x x 7 phi per object, "
        "|phi| <= 0.5 rad) in the runs that tried them; the first two were measured in an earlier "
        "version of the scan, the others against this report's scan:\n"
    )
    md.append(
        fmt_table(
            [
                "MuJoCo taxel",
                "corr >= 0.85 (box / ramp_up / convex)",
                "the kept 5 mm spheres in the same scan",
                "cost",
            ],
            [
                [
                    "4 spheres of r = 0.45 mm at the fast model's read-out points",
                    "98.7 / 98.4 / 99.0 %",
                    "96.7 / 96.5 / 97.7 %",
                    "about 2x slower, 0.5-2 % hit the step limit",
                ],
                [
                    "spheres of r = 0.1-0.2 mm, or vertical capsules",
                    "96-97 %",
                    "96.7 / 96.5 / 97.7 %",
                    "up to 20 of 1,127 unsettled, capsules 3x slower",
                ],
                [
                    "one flat 5 x 5 mm cell pad per taxel (convex mesh, one contact)",
                    "94.0 / 95.9 / 91.8 %",
                    "97.9 / 96.8 / 99.1 %",
                    "about 1.5x slower; edges up to 0.8 mm higher",
                ],
                [
                    "4 flat pads per taxel, 1.25 mm wide",
                    "95.4 / 95.9 / 94.5 %",
                    "97.9 / 96.8 / 99.1 %",
                    "5-25x slower",
                ],
                [
                    "spheres, each contact's force put in the cell under its contact point",
                    "98.1 / 97.1 / 99.2 %",
                    "97.9 / 96.8 / 99.1 %",
                    "as fast; mean correlation 0.971-0.989",
                ],
            ],
        )
        + "\n"
    )
    md.append(
        "A flat pad reports its deepest point, so an edge loads the pad that holds the edge itself, "
        "where the foam's read-out points see the strip beside it; a small probe near an edge is pushed "
        "out sideways (MuJoCo measures depth along the shortest way out). None of these did better than "
        "the sphere taxels by more than two points, and none removes the cause, which the fast "
        "model shares with itself at a finer read-out. The sphere taxels were kept.\n"
    )
    md.append("## Height-field objects and the 4-D glance\n")
    md.append(HEIGHT_FIELD_SECTION)
    md.append("## Configuration used\n")
    md.append("```\n" + "\n".join(f"{k} = {v}" for k, v in asdict(cfg).items()) + "\n```\n")
    write_text(out, "\n".join(md), what="report")
    print(f"wrote {out} and {len(figures) + 3} pictures in {img_dir}")
    for row in main_rows:
        print("  ", " | ".join(row))


if __name__ == "__main__":
    main()
