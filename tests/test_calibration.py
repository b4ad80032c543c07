"""Read-out calibration (``ham table calibrate``): a simulator's glance table carried onto a pad
by a read-out fitted to a few of the pad's recorded glances."""

import json

import h5py
import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.world.calibration import Readout, calibrate_table, fit_readout
from ham.world.table import GlanceTable, table_info, verify_table
from tests.conftest import ok, one_line_error, run_ham_inprocess

RECORDED = [0, 2, 4, 6, 8]  # a 5 x 5 grid's points on the 9 x 9 table's


def _gaussian(k: int, sigma: float, gain: float) -> np.ndarray:
    u = np.arange(k) - k // 2
    g = np.exp(-(u[:, None] ** 2 + u[None, :] ** 2) / (2 * sigma**2))
    return gain * g / g.sum()


def _record(images: np.ndarray, names: list[str], path, at=RECORDED) -> None:
    """``images`` ``(objects, 9, 9, N, N)`` at the grid points ``at`` as recorded glances."""
    np.savez(path, **{n: images[i][np.ix_(at, at)] for i, n in enumerate(names)})


def _cosine(a: torch.Tensor, b: torch.Tensor) -> float:
    """Mean cosine of the images (as the L2-normalizing model compares them)."""
    a, b = a.reshape(-1, a.shape[-1] ** 2).double(), b.reshape(-1, b.shape[-1] ** 2).double()
    n = torch.nn.functional.normalize
    return (n(a, dim=1) * n(b, dim=1)).sum(1).mean().item()


def test_a_known_readout_is_recovered_everywhere(small_table, tmp_path):
    table = GlanceTable.load(small_table)
    truth = Readout(_gaussian(5, 1.2, 3.0), 0.0, 1.0, 0)
    pad = truth.apply(table.pressure.numpy())
    _record(pad, table.objects, tmp_path / "rec.npz")
    out, readout = calibrate_table(small_table, tmp_path / "rec.npz", tmp_path / "cal.h5",
                                   kernel=5)  # fmt: skip
    assert readout.glances == 4 * 25 and min(readout.r2, readout.r2_held_out) > 1 - 1e-9
    assert np.allclose(readout.kernel, truth.kernel, atol=1e-9) and abs(readout.bias) < 1e-6
    info = verify_table(out)
    assert info.simulator["simulator"] == "calibrated" and info.simulator["pose_offset"] == 0
    assert info.simulator["readout"]["glances"] == 100 and info.objects == table.objects
    cal = GlanceTable.load(out)  # every glance, the 56 of 81 poses not recorded too
    scale = float(pad.max())
    assert torch.allclose(cal.pressure, torch.from_numpy(pad), atol=1e-4 * scale)
    with h5py.File(small_table) as a, h5py.File(out) as b:  # the simulator's forces and heights
        for key in ("force", "z"):
            assert np.array_equal(a[f"objects/convex/{key}"][...], b[f"objects/convex/{key}"][...])
    # a gain and an offset alone cannot explain the blur
    _, gain = calibrate_table(small_table, tmp_path / "rec.npz", tmp_path / "k1.h5", kernel=1)
    assert gain.r2 < 0.95


def test_a_few_objects_recorded_carry_every_object(small_table, tmp_path):
    """Glances of two objects, in any order, calibrate all four (the same read-out)."""
    table = GlanceTable.load(small_table)
    pad = Readout(_gaussian(3, 0.9, 2.0), 0.0, 1.0, 0).apply(table.pressure.numpy())
    at = np.ix_(RECORDED, RECORDED)
    np.savez(tmp_path / "two.npz", convex=pad[2][at], box=pad[0][at])
    out, readout = calibrate_table(small_table, tmp_path / "two.npz", tmp_path / "cal.h5",
                                   kernel=3)  # fmt: skip
    info = table_info(out)
    assert info.objects == table.objects and readout.glances == 2 * 25
    assert info.simulator["recorded_objects"] == ["convex", "box"]
    cal = GlanceTable.load(out).pressure
    assert torch.allclose(cal, torch.from_numpy(pad), atol=1e-4 * float(pad.max()))


def test_the_fit_solves_the_least_squares_problem():
    rng = np.random.default_rng(0)
    sim = rng.random((6, 8, 8))
    pad = Readout(rng.normal(size=(3, 3)), 0.5, 1.0, 0).apply(sim) + rng.normal(0, 0.1, sim.shape)
    readout = fit_readout(sim, pad, kernel=3)
    x = torch.nn.functional.unfold(torch.from_numpy(sim)[:, None], 3, padding=1)
    x = np.concatenate([x.transpose(1, 2).reshape(-1, 9).numpy(), np.ones((6 * 64, 1))], 1)
    w, *_ = np.linalg.lstsq(x, pad.reshape(-1).astype(np.float64), rcond=None)
    assert np.allclose(readout.kernel.reshape(-1), w[:-1]) and np.isclose(readout.bias, w[-1])
    y = pad.reshape(-1).astype(np.float64)
    r2 = 1 - ((x @ w - y) ** 2).sum() / ((y - y.mean()) ** 2).sum()
    assert np.isclose(readout.r2, r2)
    # held out: 6 glances, 6 folds of one; each predicted by the fit to the other five
    glance = np.repeat(np.arange(6), 64)
    errors = 0.0
    for j in range(6):
        fit, *_ = np.linalg.lstsq(x[glance != j], y[glance != j], rcond=None)
        errors += ((x[glance == j] @ fit - y[glance == j]) ** 2).sum()
    held_out = 1 - errors / ((y - y.mean()) ** 2).sum()
    assert np.isclose(readout.r2_held_out, held_out) and held_out < readout.r2
    assert fit_readout(sim[:1], pad[:1], kernel=3).r2_held_out is None  # one glance: no fold


def test_calibration_carries_the_fast_table_toward_mujoco_gazebo(small_table, tmp_path):
    """The real engine: the fast simulator's taxels and MuJoCo's Gazebo read-out (a few contact
    points spread by 5 mm) differ most; 9 MuJoCo glances per object make the fast table's
    other 72 poses read as MuJoCo's."""
    gazebo = tmp_path / "gz.h5"
    ok(run_ham_inprocess("table", "build", "--grid", "9", "--simulator", "mujoco", "--sensor",
                         "gazebo", "--out", str(gazebo), "--quiet"))  # fmt: skip
    pad, fast = GlanceTable.load(gazebo), GlanceTable.load(small_table)
    at = [0, 4, 8]
    _record(pad.pressure.numpy(), pad.objects, tmp_path / "rec.npz", at)
    out, readout = calibrate_table(small_table, tmp_path / "rec.npz", tmp_path / "cal.h5")
    cal = GlanceTable.load(out)
    unseen = torch.ones(9, 9, dtype=torch.bool)
    unseen[np.ix_(at, at)] = False
    before = _cosine(pad.pressure[:, unseen], fast.pressure[:, unseen])
    after = _cosine(pad.pressure[:, unseen], cal.pressure[:, unseen])
    assert after > before + 0.25, (before, after)
    assert 0.5 < readout.r2 < 1


def test_the_cli_calibrates_and_says_the_fit(ham_cli, small_table, tmp_path):
    table = GlanceTable.load(small_table)
    _record(Readout(_gaussian(3, 1.0, 1.0), 0.0, 1.0, 0).apply(table.pressure.numpy()),
            table.objects, tmp_path / "rec.npz", [0, 8])  # fmt: skip
    r = ok(ham_cli("table", "calibrate", small_table, str(tmp_path / "rec.npz"), "--kernel", "3",
                   "--out", str(tmp_path / "cal.h5")))  # fmt: skip
    assert (
        "a 3 x 3 read-out fitted to 16 recorded glances explains 1.000 of their variance "
        "(1.000 held out); wrote " in r.stdout
    )
    info = table_info(tmp_path / "cal.h5")
    assert info.command.startswith("ham table calibrate") and info.grid == 9
    shown = ok(ham_cli("table", "info", str(tmp_path / "cal.h5"))).stdout
    assert "  read-out:  a 3 x 3 read-out fitted to 16 recorded glances explains 1.000" in shown
    assert info.simulator["recorded_grid"] == [2, 2]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"kernel": 4}, "kernel = 4; accepted: an odd integer from 1 to 31"),
        ({"kernel": 0}, "kernel = 0; accepted: an odd integer"),
        ({"kernel": 33}, "kernel = 33; accepted: an odd integer from 1 to 31"),
        ({"kernel": True}, "kernel = True; accepted: an integer"),
        ({"kernel": 3.0}, "kernel = 3.0; accepted: an integer"),
        ({"order": True}, "recorded glances of cup, which"),
        ({"taxels": 8}, "recorded 8 x 8 images; accepted: the 16 x 16"),
        ({"dims": 3}, "has shape (2, 2, 2, 16, 16); accepted: (G_x, G_phi, N, N)"),
        ({"zeros": True}, "the recorded glances are all the same value"),
        ({"out": "cal.txt"}, "cal.txt' ends in '.txt'; accepted: a path ending in .h5"),
    ],
)
def test_bad_calibrations_are_refused_in_one_line(small_table, tmp_path, change, message):
    names = ["box", "ramp_up", "convex", "ramp_down"]
    if change.get("order"):
        names = ["ramp_up", "cup", "convex"]
    n = change.get("taxels", 16)
    shape = (2,) * change.get("dims", 2) + (n, n)
    value = 0.0 if change.get("zeros") else 1.0
    np.savez(tmp_path / "rec.npz", **{name: np.full(shape, value) for name in names})
    out = tmp_path / change.get("out", "cal.h5")
    with pytest.raises(HamError, match=None) as info:
        calibrate_table(small_table, tmp_path / "rec.npz", out, kernel=change.get("kernel", 3))
    assert message in str(info.value) and "\n" not in str(info.value)
    assert not out.exists() and list(tmp_path.iterdir()) == [tmp_path / "rec.npz"]


def test_the_cli_refuses_a_bad_kernel_in_one_line(ham_main, small_table, tmp_path):
    np.savez(tmp_path / "rec.npz", box=np.ones((2, 2, 16, 16)))
    r = ham_main("table", "calibrate", small_table, str(tmp_path / "rec.npz"), "--kernel", "2",
                 "--out", str(tmp_path / "cal.h5"))  # fmt: skip
    assert r.returncode != 0 and "kernel = 2; accepted: an odd integer" in one_line_error(r)


def test_a_table_over_other_pose_dims_keeps_its_layout_and_heights(tmp_path):
    """The next world's kind of table (format 2: poses x, y, with contact heights): the
    calibrated table has its grid, compression and heights, and the read-out's images."""
    from ham.world.config import WorldConfig
    from ham.world.table import build_table

    world = WorldConfig(objects="curvature2d", pose_dims=("x", "y"))
    sim = build_table(world, "5,7", tmp_path / "xy.h5", progress=False, compression="lzf")
    table = GlanceTable.load(sim)
    truth = Readout(_gaussian(3, 0.8, 2.0), 1.5, 1.0, 0)
    pad = truth.apply(table.pressure.numpy())
    np.savez(tmp_path / "rec.npz", **{n: pad[i][np.ix_([0, 2, 4], [0, 3, 6])]
                                      for i, n in enumerate(table.objects)})  # fmt: skip
    out, readout = calibrate_table(sim, tmp_path / "rec.npz", tmp_path / "cal.h5", kernel=3)
    info = table_info(out)
    assert info.format_version == 2 and info.grid_shape == (5, 7) and info.compression == "lzf"
    assert info.pose_dims == ("x", "y") and info.simulator["recorded_grid"] == [3, 3]
    cal = GlanceTable.load(out)
    assert torch.allclose(cal.pressure, torch.from_numpy(pad), atol=1e-4 * float(pad.max()))
    assert torch.equal(cal.height, table.height) and cal.knows_heights
    assert abs(readout.bias - 1.5) < 1e-6


def test_a_corrupt_table_is_refused_in_one_line(small_table, tmp_path):
    import shutil

    bad = tmp_path / "bad.h5"
    shutil.copyfile(small_table, bad)
    with h5py.File(bad, "r+") as f:
        f["objects/convex/pressure"][3, 4, 5, 6] = np.nan
    np.savez(tmp_path / "rec.npz", **{n: np.ones((2, 2, 16, 16)) for n in
                                      ("box", "ramp_up", "convex", "ramp_down")})  # fmt: skip
    with pytest.raises(HamError) as info:
        calibrate_table(bad, tmp_path / "rec.npz", tmp_path / "cal.h5", kernel=3)
    assert "objects/convex/pressure holds nan at index (3, 4, 5, 6)" in str(info.value)
    assert not (tmp_path / "cal.h5").exists()


def test_a_readout_fitted_before_is_applied_to_another_table(small_table, tmp_path, ham_cli):
    """--readout-from: the read-out of one calibration applied to a table of other objects
    (here the next world's, over x, y), with no glance of them recorded. The pad here is a
    known read-out, so it carries exactly; measured on MuJoCo's glances it carries within a
    kind of contact only (docs/sim_to_real.md)."""
    from ham.world.calibration import carry_readout
    from ham.world.config import WorldConfig
    from ham.world.sensor import SensorConfig
    from ham.world.table import build_table

    table = GlanceTable.load(small_table)
    truth = Readout(_gaussian(5, 1.1, 1.7), 0.0, 1.0, 0)
    _record(truth.apply(table.pressure.numpy()), table.objects, tmp_path / "rec.npz")
    first, fitted = calibrate_table(small_table, tmp_path / "rec.npz", tmp_path / "cal.h5",
                                    kernel=5)  # fmt: skip
    others = build_table(WorldConfig(objects="curvature2d", pose_dims=("x", "y")), 4,
                         tmp_path / "xy.h5", progress=False)  # fmt: skip
    r = ok(ham_cli("table", "calibrate", str(others), "--readout-from", str(first), "--out",
                   str(tmp_path / "xy_cal.h5")))  # fmt: skip
    assert (
        f"fitted to 100 recorded glances explains 1.000 of their variance (1.000 held out) "
        f"(from {first}); wrote" in r.stdout
    )
    carried = GlanceTable.load(tmp_path / "xy_cal.h5")
    want = truth.apply(GlanceTable.load(others).pressure.numpy())
    assert torch.allclose(carried.pressure, torch.from_numpy(want), atol=1e-4 * float(want.max()))
    info = table_info(tmp_path / "xy_cal.h5")
    assert info.simulator["readout_from"] == "cal.h5" and info.simulator["recorded"] == "rec.npz"
    assert info.simulator["table"]["simulator"] == "fast" and info.pose_dims == ("x", "y")
    # another pad's table is refused: 8 x 8 taxels
    small = build_table(WorldConfig(sensor=SensorConfig(taxels=8)), 3, tmp_path / "t8.h5",
                        progress=False)  # fmt: skip
    with pytest.raises(HamError, match="reads 16 x 16 images; accepted: a table of that pad"):
        carry_readout(small, first, tmp_path / "no.h5")
    assert not (tmp_path / "no.h5").exists()
    # a read-out changed in the file is refused, not applied: the record checksum, then (for a
    # table without one, from before it) the read-out's own check
    with h5py.File(first, "r+") as f:
        made = json.loads(f.attrs["simulator"])
        made["readout"]["kernel"] = [[1.0, 2.0]]
        f.attrs["simulator"] = json.dumps(made)
    with pytest.raises(HamError, match="is corrupt: its attributes or force/height/contact"):
        carry_readout(others, first, tmp_path / "no.h5")
    with h5py.File(first, "r+") as f:
        del f.attrs["record_checksum"]
    with pytest.raises(HamError, match="its read-out's kernel \\(1, 2\\) or bias"):
        carry_readout(others, first, tmp_path / "no.h5")
