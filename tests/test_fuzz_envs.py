"""The environments' odd-value sweep (tests/fuzz_envs.py): it passes, and it flags."""

from __future__ import annotations

import numpy as np

from tests import fuzz_envs


def test_the_sweep_of_the_envs_flags_nothing(capsys):
    assert fuzz_envs.main([]) == 0
    out = capsys.readouterr().out
    assert "1138 calls: 0 flagged" in out
    for name in ("haptic", "haptic-vector", "ap", "ap-vector"):
        assert f"{name}: " in out


def test_the_sweep_flags_a_pose_check_without_its_nan_test(monkeypatch, capsys):
    from ham.envs import haptic

    def clipped(pose, n, k=2):  # a bug: NaN is clipped to NaN and glanced at
        return np.clip(np.asarray(pose, dtype=np.float64).reshape(n, k), -1, 1).astype(np.float32)

    monkeypatch.setattr(haptic, "check_poses", clipped)
    assert fuzz_envs.main(["haptic"]) > 0
    out = capsys.readouterr().out
    assert "FLAG haptic.step(pose=array([nan, nan])): accepted" in out
    assert "FLAG haptic.step(pose=nan): ValueError: cannot reshape" in out  # a traceback
    assert "FLAG haptic.step(pose='abc'): ValueError" in out
    assert "FLAG haptic.step(prediction" not in out  # the prediction's own check still holds
