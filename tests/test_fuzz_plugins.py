"""The odd-value sweep of the user's own code (tests/fuzz_plugins.py): it passes, and it flags.

The whole sweep (371 cases, about a minute) runs by hand; here every part runs, the simulator
part on three of its ten fields, its describe() and the 4-d table's height.
"""

from __future__ import annotations

import pytest

from tests import fuzz_plugins


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz-plugins")
    return root, fuzz_plugins.fixtures(root)


def _cases(part: str) -> list[fuzz_plugins.Case]:
    cases = fuzz_plugins.PARTS[part]()
    if part == "simulator":
        cases = [
            c
            for c in cases
            if c.name.split("=")[0] in ("pressure", "z", "contact", "describe", "4d-height")
        ]
    return cases


@pytest.mark.parametrize("part", list(fuzz_plugins.PARTS))
def test_every_odd_value_of_a_part_is_refused_or_taken_as_its_contract_says(sweep, part):
    root, fixtures = sweep
    cases = _cases(part)
    flagged = [
        (c.name, why) for c in cases if (why := fuzz_plugins.run_case(c, root, fixtures, 120))
    ]
    assert flagged == []
    assert {c.expect for c in cases} >= {"refuse", "take"}  # both kinds tried in every part


def test_the_sweep_flags_a_missing_check(sweep, monkeypatch):
    from ham.model import agent
    from ham.world import simulators

    root, fixtures = sweep
    cases = {f"{c.part}:{c.name}": c for p in fuzz_plugins.PARTS for c in fuzz_plugins.PARTS[p]()}
    # the glance check gone: a NaN image goes on into the table build (a traceback there)
    monkeypatch.setattr(simulators.CheckedSimulator, "_checked", lambda self, r, n: r)
    why = fuzz_plugins.run_case(cases["simulator:pressure=nan"], root, fixtures, 120)
    assert why.startswith(("took a value", "traceback")), why
    # the model's per-glance check of a policy's poses gone: poses that require grad go on
    monkeypatch.setattr(agent, "check_poses", lambda *a: None)
    monkeypatch.setattr("ham.model.plugin.check_poses", lambda *a: None)
    why = fuzz_plugins.run_case(cases["policy:grad--table"], root, fixtures, 120)
    assert why.startswith(("took a value", "traceback")), why
    assert fuzz_plugins.run_case(cases["policy:edges--table"], root, fixtures, 120) == ""
