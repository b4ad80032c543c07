"""Speed and accuracy of a mesh's top (``HapticObject.from_mesh``, ``mesh_top``) on icospheres.

Run: ``.venv/bin/python benchmarks/bench_mesh_top.py``. Prints one line per mesh: CPU seconds of
the rasterization and of the whole constructor (best of 3), and the largest distance between the
rasterized top and the exact sphere inside 0.95 of its radius (the mesh's faceting).
"""

from __future__ import annotations

import time

import numpy as np
import trimesh

from ham.world.objects import HapticObject, mesh_top

RADIUS = 0.04
PITCH = 0.0005


def main() -> None:
    for sub in (3, 4, 5):
        mesh = trimesh.creation.icosphere(subdivisions=sub, radius=RADIUS)
        whole = []
        for _ in range(3):
            t = time.process_time()
            HapticObject.from_mesh(f"sphere{sub}", mesh, pitch=PITCH)
            whole.append(time.process_time() - t)
        tris = np.asarray(mesh.triangles) + np.array([0.0, 0.0, RADIUS])
        xs = np.linspace(-RADIUS, RADIUS, round(2 * RADIUS / PITCH) + 1)
        raster = []
        for _ in range(3):
            t = time.process_time()
            top = mesh_top(tris, xs, xs)
            raster.append(time.process_time() - t)
        gx, gy = np.meshgrid(xs, xs)
        r2 = gx**2 + gy**2
        exact = RADIUS + np.sqrt(np.clip(RADIUS**2 - r2, 0, None))
        inner = r2 < (0.95 * RADIUS) ** 2
        err = np.abs(top - exact)[inner].max()
        print(
            f"icosphere {len(mesh.faces):>6} faces, {len(xs)} x {len(xs)} grid: mesh_top "
            f"{min(raster):.3f} s, from_mesh {min(whole):.3f} s CPU (best of 3); "
            f"max |top - sphere| (r < 0.95 R) {err * 1e3:.3f} mm"
        )


if __name__ == "__main__":
    main()
