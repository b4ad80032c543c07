"""The main job on built-in defaults (``make demo`` / ``ham demo``).

Builds the default glance table, draws a glance on every paper object and the table's images,
then (when the agent is available) trains a HAM briefly, evaluates it and writes a report.
"""

from __future__ import annotations

from pathlib import Path

from ham.world import objects
from ham.world.config import WorldConfig, make_simulator
from ham.world.drawing import draw_glance, draw_objects, draw_table_grid
from ham.world.files import write_json
from ham.world.table import GlanceTable, build_table, grid_values

#: One telling pose per paper object (q_x, q_phi): where its shape shows.
DEMO_POSES = {
    "box": (0.0, 0.0),
    "ramp_up": (0.5, 0.0),
    "convex": (0.2, 0.15),
    "ramp_down": (-0.5, 0.0),
}


def run_demo(out: Path, *, quick: bool = False) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    world = WorldConfig()
    grid = 21 if quick else 201
    table_path = build_table(world, grid, out / "table.h5", command=f"ham demo --out {out}")
    print(f"glance table: {table_path}")
    # the line objects (paper + MHSB); the height-field sets have pictures of their own
    draw_objects(objects.resolve_set("paper") + objects.resolve_set("mhsb"), out / "objects.png")
    sim = make_simulator(world)
    pictures = []
    for oid, obj in enumerate(world.resolve_objects()):
        qx, qp = DEMO_POSES.get(obj.name, (0.0, 0.0))
        data = sim.glance([oid], [qx], [qp]).to_json(0)
        pictures.append(
            str(draw_glance(obj, data, world.sensor.size, out / f"glance_{obj.name}.png"))
        )
    table = GlanceTable.load(table_path)
    q = grid_values(table.grid)
    import numpy as np

    pick = np.round(np.linspace(0, table.grid - 1, 5)).astype(int)
    for oi, name in enumerate(table.objects):
        p = table.pressure[oi].numpy()[np.ix_(pick, pick)]
        draw_table_grid(p, (q[pick], q[pick]), f"{name}: table images", out / f"table_{name}.png")
    summary = {"table": str(table_path), "glance_pictures": pictures}
    try:
        from ham.experiments.demo_agent import run_agent_demo  # added by the agent issue
    except ModuleNotFoundError:
        run_agent_demo = None
    if run_agent_demo is not None:
        summary.update(run_agent_demo(out, table_path, quick=quick))
    write_json(out / "demo.json", summary)
    print(f"demo written to {out}")
    return summary
