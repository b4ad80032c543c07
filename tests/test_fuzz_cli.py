"""The odd-value sweep (tests/fuzz_cli.py) on one cheap command: it runs, and it flags."""

from __future__ import annotations

from tests import fuzz_cli


def test_the_sweep_passes_a_command_that_answers_every_odd_value(capsys):
    assert fuzz_cli.main(["table-info", "--limit", "60"]) == 0
    out = capsys.readouterr().out
    assert f"{len(fuzz_cli.ODD)} calls in" in out and ": 0 flagged, 0 slow" in out


def test_the_sweep_flags_a_traceback_and_an_accepted_nan(monkeypatch, capsys):
    import importlib

    cli = importlib.import_module("ham.cli.main")  # (ham.cli.main is also the function's name)

    def table_info(args):  # a command with two bugs: a traceback and a value taken silently
        if args.file == "abc":
            raise ValueError("boom")
        return 0

    monkeypatch.setattr(cli, "cmd_table_info", table_info)
    assert fuzz_cli.main(["table-info", "--limit", "60"]) > 0
    out = capsys.readouterr().out
    assert "FLAG table-info 2 'abc': traceback" in out and "ValueError: boom" in out
    assert "FLAG table-info 2 '': accepted" not in out  # '' is refused before the command
    assert "FLAG table-info 2 '/dev/null'" not in out  # a path option may take any name
