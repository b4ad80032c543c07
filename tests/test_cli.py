"""The real ``ham`` CLI in a subprocess: the contract other work builds on."""

import json

import numpy as np
import pytest


def test_glance_json_contract(ham_cli):
    r = ham_cli("glance", "--object", "box", "--x", "0", "--phi", "0", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    p = np.array(d["pressure"])
    assert p.shape == (16, 16) and np.allclose(p, 312.5, rtol=1e-4)  # raw, not normalized
    assert d["force"] == pytest.approx(2.0, abs=1e-4)
    assert d["contact"] is True and 0.04 < d["z"] < 0.046


def test_glance_picture(ham_cli, tmp_path):
    out = tmp_path / "g.png"
    r = ham_cli("glance", "--object", "3", "--x", "-0.5", "--phi", "0.1", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "args, message",
    [
        (
            ["glance", "--object", "box", "--x", "nan", "--phi", "0"],
            "q_x = nan is outside the accepted range [-1, 1]",
        ),
        (
            ["glance", "--object", "box", "--x", "0", "--phi", "-1.2"],
            "q_phi = -1.2 is outside the accepted range [-1, 1]",
        ),
        (["glance", "--object", "sphere", "--x", "0", "--phi", "0"], "unknown object 'sphere'"),
        (
            ["glance", "--object", "99", "--x", "0", "--phi", "0"],
            "unknown object id 99; accepted: 0..40",
        ),
        (
            ["glance", "--object", "box", "--x", "0", "--phi", "0", "--simulator", "ode"],
            "unknown simulator 'ode'",
        ),
        (["table", "info", "/nonexistent/t.h5"], "does not exist"),
        (
            ["table", "build", "--grid", "1", "--out", "x.h5"],
            "grid = 1; accepted: an integer 2..2001",
        ),
        (["objects", "--set", "box,cube"], "unknown object 'cube'"),
        (
            ["objects", "--set", "papr"],
            "unknown object set or object 'papr'; accepted: a set (paper, mhsb,",
        ),
    ],
)
def test_bad_input_is_one_line_without_traceback(ham_cli, args, message, tmp_path):
    r = ham_cli(*args, cwd=tmp_path)
    assert r.returncode != 0
    assert "Traceback" not in r.stderr
    assert message in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_unreadable_table_file(ham_cli, tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"\x00" * 100)
    r = ham_cli("table", "info", str(bad))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "cannot read glance table" in r.stderr


def test_table_build_info_show(ham_cli, ham_main, tmp_path):
    out = tmp_path / "t.h5"
    r = ham_cli("table", "build", "--objects", "paper", "--grid", "9", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    r = ham_cli("table", "info", str(out), "--json")
    info = json.loads(r.stdout)
    assert info["grid"] == 9 and info["command"].startswith("ham table build")
    png = tmp_path / "show.png"
    r = ham_cli("table", "show", str(out), "--object", "ramp_up", "--n", "3", "--out", str(png))
    assert r.returncode == 0, r.stderr
    assert png.exists()
    r = ham_main("table", "show", str(out), "--object", "ridge", "--out", str(png))
    assert r.returncode == 2 and "not in table" in r.stderr


def test_objects_listing(ham_cli, tmp_path):
    r = ham_cli("objects", "--json", "--out", str(tmp_path / "o.png"))
    rows = json.loads(r.stdout)
    assert [x["name"] for x in rows[:4]] == ["box", "ramp_up", "convex", "ramp_down"]
    assert {"ridge", "trough", "step", "double_ridge"} <= {x["name"] for x in rows}
    assert (tmp_path / "o.png").exists()


def test_demo_quick_runs_the_whole_chain(ham_cli, tmp_path):
    out = tmp_path / "demo"
    r = ham_cli("demo", "--quick", "--out", str(out))
    assert r.returncode == 0, r.stderr
    for name in ("table.h5", "objects.png", "glance_box.png", "training_curve.png", "heatmap.png"):
        assert (out / name).exists(), name
    summary = json.loads((out / "demo.json").read_text())
    assert summary["agent"]["steps"] == 20
    assert 0.0 <= summary["agent"]["evaluation"]["accuracy"] <= 1.0
    assert "accuracy after the last glance" in (out / "report.md").read_text()


@pytest.mark.parametrize(
    "error",
    [
        MemoryError("Unable to allocate 95.4 GiB for an array"),  # NumPy
        RuntimeError(
            "DefaultCPUAllocator: can't allocate memory: you tried to allocate 4e13 bytes"
        ),
    ],
)
def test_out_of_memory_is_one_line(monkeypatch, capsys, error):
    # An allocation the machine refuses (mocked: a real one would take the machine's memory)
    from ham.cli.main import main

    def run_out(args):
        raise error

    monkeypatch.setattr("ham.cli.agent.cmd_evaluate", run_out)
    assert main(["evaluate", "somewhere"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("ham: error: out of memory (")
    assert "accepted: a request that fits this machine" in err[0]


def test_other_runtime_errors_are_not_called_out_of_memory(monkeypatch):
    from ham.cli.main import main

    def fail(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr("ham.cli.agent.cmd_evaluate", fail)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["evaluate", "somewhere"])
