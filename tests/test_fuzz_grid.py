"""The grid file format's odd-value sweep (tests/fuzz_grid.py): it passes, and it flags."""

from __future__ import annotations

from tests import fuzz_grid


def test_the_sweep_of_the_grid_format_flags_nothing(capsys):
    assert fuzz_grid.main([]) == 0
    calls = (len(list(fuzz_grid.places(fuzz_grid.BASE))) + len(fuzz_grid.UNKNOWN)) * len(
        fuzz_grid.ODD
    )
    assert f"{calls} calls: 0 flagged" in capsys.readouterr().out
    assert calls > 500


def test_the_sweep_flags_a_traceback(monkeypatch):
    from ham.experiments import grid

    def broken(self, table=None):  # a bug: a TypeError deep inside
        raise TypeError("boom")

    monkeypatch.setattr(grid.Grid, "jobs", broken)
    calls, flags = fuzz_grid.sweep()
    assert flags and all("TypeError: boom" in f for f in flags)
    assert len(flags) < calls  # the values refused before it still are
