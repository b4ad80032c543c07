"""The Python API's odd-value sweep (tests/fuzz_api.py) on a cheap function: it runs, it flags."""

from __future__ import annotations

from tests import fuzz_api


def test_the_sweep_passes_a_function_that_checks_every_argument(capsys):
    assert fuzz_api.main(["table_info", "verify_table"]) == 0
    out = capsys.readouterr().out
    calls = 2 * 2 * len(fuzz_api.ODD)  # each: its path and an unknown keyword
    assert f"{calls} calls: 0 flagged" in out


def test_the_sweep_flags_a_traceback_an_accepted_nan_and_a_leftover(tmp_path):
    from ham.errors import HamError

    def f(x: int = 0) -> None:  # three bugs: a traceback, NaN taken, a refusal that writes
        if x == "abc":
            raise ValueError("boom")
        if x == -1:
            open("left.txt", "w").close()
            raise HamError("x = -1")

    calls, flags = fuzz_api.sweep("f", f, {}, tmp_path)
    assert calls == 2 * len(fuzz_api.ODD)
    text = "\n".join(flags)
    assert "FLAG f(x='abc'): ValueError: boom" in text
    assert "FLAG f(x=nan): accepted" in text and "FLAG f(x=inf): accepted" in text
    assert "FLAG f(x=-1): refused, and left" in text
    assert "FLAG f(fuzz_unknown=0): TypeError" in text  # no check of its keywords
    assert "FLAG f(x=0)" not in text and "FLAG f(x='')" not in text
