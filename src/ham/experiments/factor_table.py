"""The factor table (issue 13): what moves Table 1's numbers between the paper's world and ours.

A factor grid (``docs/grids/factors.toml``, run by ``ham reproduce grid``) trains the full model
at 1-4 glances in the ``paper-gazebo`` world preset (cell ``preset-g<G>``) and with one factor
changed at a time (cell ``<factor>-g<G>``). This module turns the grid's ``results.json`` into
the table: per factor and glance count, the best accuracy within a run (Table 1's entry), mean
± s.e.m. over seeds, its change against the preset, the final checkpoint's re-evaluation with
sampled and with mean poses, and the paper's Table 1 beside it::

    python -m ham.experiments.factor_table runs/factors --out docs/results/factor_table

writes ``factor_table.md``, ``factor_table.json`` and ``factor_table.png`` (atomically).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

from ham.errors import HamError
from ham.experiments.reproduce import PAPER_TABLE1

PRESET = "preset"
_CELL = re.compile(r"^(?P<factor>.+)-g(?P<glances>\d+)$")
#: What each factor of docs/grids/factors.toml changes, for the table.
FACTOR_TEXT = {
    "preset": "paper-gazebo preset (Gazebo read-out, authors' pose, sampled-pose evaluation)",
    "taxels": "read-out: taxels (fast simulator) instead of Gazebo",
    "paper-pose": "pose mapping: the paper's (phi = q pi/2) instead of the authors'",
    "mean-eval": "evaluation: mean poses instead of sampled",
    "mean-loss": "classification loss: mean over the batch instead of sum",
    "truncated-bptt": "BPTT: truncated between glances (authors' code) instead of full",
    "lr-T200": "lr decay step T = 200 (authors' code) instead of 800",
    "l1": "normalization: L1 (authors' code) instead of L2",
}


def _num(d: dict | None) -> dict:
    d = d or {}
    return {"mean": d.get("mean", math.nan), "sem": d.get("sem", math.nan), "n": d.get("n", 0)}


def factor_table(results: dict) -> dict:
    """``{"glances": [...], "factors": {factor: {G: entry}}}`` from a factor grid's results.

    An entry: ``best`` (mean, sem, n over seeds), ``delta`` (its mean minus the preset's, with
    the two s.e.m. combined), ``final_sample`` and ``final_mean`` (the final checkpoint's
    re-evaluations, when the grid asked for them), ``paper`` (Table 1's full model).
    """
    cells: dict[str, dict[int, dict]] = {}
    for c in results.get("cells", []):
        m = _CELL.match(c["cell"])
        if m is None:
            raise HamError(f"cell {c['cell']!r}: a factor cell is named <factor>-g<glances>")
        entry = {"best": _num(c.get("best_accuracy")), "runs": c.get("finished", 0),
                 "steps": c.get("steps")}  # fmt: skip
        for e in c.get("evaluations", []):
            entry[f"final_{e['policy']}"] = _num(e.get("accuracy"))
        paper = PAPER_TABLE1["full"].get(int(m["glances"]))
        entry["paper"] = list(paper) if paper else None
        cells.setdefault(m["factor"], {})[int(m["glances"])] = entry
    if PRESET not in cells:
        raise HamError(f"no {PRESET!r} cells in the results; accepted: a factor grid's results")
    glances = sorted({g for f in cells.values() for g in f})
    for f in cells.values():
        for g, e in f.items():
            base = cells[PRESET].get(g, {}).get("best", _num(None))
            d = e["best"]["mean"] - base["mean"]
            s = math.sqrt(e["best"]["sem"] ** 2 + base["sem"] ** 2)
            e["delta"] = {"mean": d, "sem": s}
    return {"glances": glances, "factors": cells}


def _fmt(x: dict) -> str:
    if not x or x.get("n", 1) == 0 or math.isnan(x["mean"]):
        return "—"
    if math.isnan(x.get("sem", math.nan)):
        return f"{x['mean']:.3f}"
    return f"{x['mean']:.3f} ± {x['sem']:.3f}"


def _delta(x: dict) -> str:
    if math.isnan(x["mean"]):
        return "—"
    return f"{x['mean']:+.3f}"


def table_markdown(t: dict) -> str:
    """Best accuracy per factor x glances, with its change against the preset."""
    gs = t["glances"]
    lines = ["| setting | " + " | ".join(f"{g} glance{'s' * (g > 1)}" for g in gs) + " |",
             "|---|" + "---|" * len(gs)]  # fmt: skip
    for f, row in t["factors"].items():
        cells = []
        for g in gs:
            e = row.get(g)
            if e is None or e["best"]["n"] == 0:
                cells.append("—")
            elif f == PRESET:
                cells.append(f"**{_fmt(e['best'])}**")
            else:
                cells.append(f"{_fmt(e['best'])} ({_delta(e['delta'])})")
        lines.append(f"| `{f}`: {FACTOR_TEXT.get(f, f)} | " + " | ".join(cells) + " |")
    paper = [PAPER_TABLE1["full"].get(g) for g in gs]
    lines.append("| paper, Table 1 (full model) | "
                 + " | ".join(f"{p[0]:.3f} ± {p[1]:.3f}" if p else "—" for p in paper) + " |")  # fmt: skip
    return "\n".join(lines)


def evaluations_markdown(t: dict) -> str:
    """The final checkpoint re-evaluated with sampled and with mean poses, per factor."""
    gs = t["glances"]
    head = " | ".join(f"G={g}: sampled | G={g}: mean" for g in gs)
    lines = [f"| setting | {head} |", "|---|" + "---|---|" * len(gs)]
    for f, row in t["factors"].items():
        cells = []
        for g in gs:
            e = row.get(g, {})
            cells += [_fmt(e.get("final_sample")), _fmt(e.get("final_mean"))]
        lines.append(f"| `{f}` | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def draw(t: dict, path: Path) -> None:
    """Grouped bars: best accuracy per glance count, one bar per setting, s.e.m. as error bars,
    the paper's Table 1 as black ticks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ham.world.drawing import save_figure

    gs, factors = t["glances"], list(t["factors"])
    width = 0.8 / len(factors)
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for i, f in enumerate(factors):
        xs = [j + (i - (len(factors) - 1) / 2) * width for j in range(len(gs))]
        e = [t["factors"][f].get(g, {}).get("best", _num(None)) for g in gs]
        ax.bar(xs, [x["mean"] for x in e], width, yerr=[0 if math.isnan(x["sem"]) else x["sem"]
               for x in e], label=f, capsize=2)  # fmt: skip
    for j, g in enumerate(gs):
        p = PAPER_TABLE1["full"].get(g)
        if p:
            ax.hlines(p[0], j - 0.42, j + 0.42, colors="k", linewidth=2,
                      label="paper" if j == 0 else None)  # fmt: skip
    ax.set_xticks(range(len(gs)), [f"{g} glance{'s' * (g > 1)}" for g in gs])
    ax.set_ylim(0.2, 1.02)
    ax.set_ylabel("best accuracy (mean ± s.e.m. over seeds)")
    ax.set_title("Table 1 rows 1-4, full model: paper-gazebo preset and one factor changed")
    ax.legend(fontsize=7, ncol=3, loc="upper left")
    fig.tight_layout()
    save_figure(fig, path, tight=False, what="figure")


def write(run_dir: str | Path, out: str | Path) -> dict:
    """Read ``run_dir/results.json`` and write ``out.md``, ``out.json`` and ``out.png``."""
    from ham.world.files import write_json, write_text

    path = Path(run_dir) / "results.json"
    try:
        results = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise HamError(f"cannot read {str(path)!r}: {exc}") from None
    t = factor_table(results)
    out = Path(out)
    write_json(out.with_suffix(".json"), t, default=str)
    md = (table_markdown(t) + "\n\nFinal checkpoint re-evaluated (20 batches):\n\n"
          + evaluations_markdown(t) + "\n")  # fmt: skip
    write_text(out.with_suffix(".md"), md)
    draw(t, out.with_suffix(".png"))
    return t


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ham.experiments.factor_table",
                                description=__doc__.split("\n\n")[0])  # fmt: skip
    p.add_argument("run_dir", help="the factor grid's output folder (ham reproduce grid --out)")
    p.add_argument("--out", required=True, help="path prefix of the .md, .json and .png")
    args = p.parse_args(argv)
    try:
        write(args.run_dir, args.out)
    except HamError as exc:
        print(f"factor_table: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}.md, .json, .png")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
