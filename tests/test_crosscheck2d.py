"""The MuJoCo-vs-fast cross-check on curvature2d: every pose of a table's lattice (issue 12)."""

import math
import subprocess
import sys

import numpy as np
import pytest

from ham.errors import HamError
from ham.experiments.crosscheck2d import lattice_poses, report
from ham.world.table import grid_poses


def test_lattice_poses_are_the_tables_lattice():
    q = lattice_poses("3,2", "x,phi_y", tilt=0.5)
    assert q.shape == (6, 4)
    # columns (q_x, q_y, q_phi, q_phi_y): x and phi_y from the table's lattice, the others 0
    table = grid_poses((3, 2), 0, 6)
    np.testing.assert_array_equal(q[:, 0], table[:, 0])
    np.testing.assert_allclose(q[:, 3], table[:, 1] * 0.5 / (math.pi / 2))
    assert not q[:, 1].any() and not q[:, 2].any()
    full = lattice_poses(5, tilt=math.pi / 2)  # all four dims, the table's full tilt range
    assert full.shape == (625, 4) and full.min() == -1 and full.max() == 1


@pytest.mark.parametrize(
    "grid, dims, tilt, match",
    [
        (1, "x,y", 0.5, "accepted: an integer 2..2001"),
        ("5,5", "x,y,phi", 0.5, "accepted: one integer, or one per pose dim"),
        (5, "y,x", 0.5, "in that order"),
        (5, "x,y", 2.0, "accepted: 0 < tilt <= pi/2"),
    ],
)
def test_lattice_poses_refuse_bad_options(grid, dims, tilt, match):
    with pytest.raises(HamError, match=match):
        lattice_poses(grid, dims, tilt)


def test_cli_refuses_a_bad_grid_in_one_line():
    r = subprocess.run(
        [sys.executable, "-m", "ham.experiments.crosscheck2d", "--grid", "5,5", "--out", "x.md"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "error: grid = 5,5: 2 axes for the 4 pose dims" in r.stderr.splitlines()[-1]


def test_report_on_every_pose_of_a_small_lattice(tmp_path):
    res = report(tmp_path / "cc.md", threads=1, grid=2, tilt=0.3)
    assert res["poses_per_object"] == 16
    assert set(res["mean_corr"]) == set(res["within_1mm"]) and "bowl" in res["within_1mm"]
    # the dome: a smooth convex top, where the two simulators agree (docs/crosscheck_curvature2d.md)
    assert res["mean_corr"]["dome"] > 0.95 and res["within_1mm"]["dome"] == 1.0
    text = (tmp_path / "cc.md").read_text()
    assert "every point of the 2 x 2 x 2 x 2 lattice over `x,y,phi,phi_y` (16 per object" in text
    assert "--grid 2 --pose-dims x,y,phi,phi_y" not in text  # the API call names no CLI options
    assert (tmp_path / "img" / "crosscheck2d_saddle.png").stat().st_size > 0
