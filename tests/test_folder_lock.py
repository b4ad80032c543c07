"""One writer per folder: a run or a grid that another ham process is writing is refused.

The other process is stood in for by a lock taken in this process on another open file
description of the folder, which ``flock`` treats exactly as another process's.
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
import textwrap

from ham.world.files import folder_lock
from tests.conftest import ok, one_line_error, run_ham_inprocess

TRAIN = ("--glances", "2", "--steps", "2", "--batch-size", "8", "--eval-every", "2",
         "--eval-batches", "1", "--no-progress")  # fmt: skip


def _digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.glob("*.*")}


def test_a_run_in_use_is_neither_resumed_nor_trained_into(tmp_path, small_table):
    run = tmp_path / "r"
    ok(run_ham_inprocess("train", "--table", small_table, *TRAIN, "--out", str(run)))
    before = _digest(run)
    with folder_lock(run):
        line = one_line_error(run_ham_inprocess("train", "--resume", str(run), "--steps", "4"))
        assert f"run folder '{run}' is in use by another ham process; accepted: a folder" in line
    assert _digest(run) == before  # untouched
    ok(run_ham_inprocess("train", "--resume", str(run), "--steps", "4"))  # the lock is gone

    fresh = tmp_path / "fresh"
    fresh.mkdir()
    with folder_lock(fresh):  # another process about to write its first checkpoint there
        line = one_line_error(run_ham_inprocess("train", "--table", small_table, *TRAIN, "--out",
                                                str(fresh)))  # fmt: skip
        assert "is in use by another ham process" in line
    assert list(fresh.iterdir()) == []


def test_a_grid_folder_in_use_is_refused(tmp_path):
    grid = tmp_path / "g.toml"
    grid.write_text('name = "g"\nseeds = 1\n[table]\ngrid = 5\n[base]\nsteps = 2\n')
    out = tmp_path / "out"
    out.mkdir()
    with folder_lock(out):
        line = one_line_error(run_ham_inprocess("reproduce", "grid", str(grid), "--out",
                                                str(out), "--quiet"))  # fmt: skip
        assert f"--out '{out}' is in use by another ham process" in line
    assert list(out.iterdir()) == []


def test_the_lock_goes_with_a_killed_process(tmp_path):
    code = textwrap.dedent(f"""
        import os, sys
        from ham.world.files import folder_lock
        with folder_lock({str(tmp_path)!r}):
            print("held", flush=True)
            os.kill(os.getpid(), 9)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == -9 and r.stdout == "held\n"
    with folder_lock(tmp_path):  # free again: nothing was left on disk
        assert list(tmp_path.iterdir()) == []
