import contextlib
import io
import os
import subprocess
import sys

import pytest
import torch

# Tests run on CPU with few threads: the CI machine has 2 cores.
torch.set_num_threads(1)


def ham_command(*args: str) -> tuple[list[str], dict[str, str]]:
    """The real CLI's command line and environment (one thread, no display), for
    :func:`run_ham` and for tests that need the process itself (``subprocess.Popen``)."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    return [sys.executable, "-m", "ham", *args], env


def run_ham(*args: str, cwd=None, timeout: float = 300) -> subprocess.CompletedProcess:
    """The real CLI in a subprocess."""
    argv, env = ham_command(*args)
    return subprocess.run(argv, capture_output=True, text=True, cwd=cwd, env=env, timeout=timeout)


@contextlib.contextmanager
def registries_restored():
    """The registries of objects, simulators, cores, policies and learners (and the loaded plugins and
    simulator files) as they were before the block: an objects file, simulator file or plugin it
    loads stays out of the other tests."""
    from ham.learn import learners
    from ham.model import core, plugin, policy
    from ham.world import objects, recorded_file, simulators

    registry = (recorded_file._RAN, objects._REGISTRY, objects._ORDER, objects._ORIGIN, objects._FILES, objects._LAZY,
                core.CORES, policy.POLICIES, plugin._LOADED, simulators._SIMULATORS,
                simulators._ORIGIN, simulators._LOADED, learners.LEARNERS, learners.READS)  # fmt: skip
    saved = [r.copy() for r in registry]
    try:
        yield
    finally:
        for live, before in zip(registry, saved, strict=True):
            live.clear()
            live.extend(before) if isinstance(live, list) else live.update(before)


def run_ham_inprocess(*args: str, cwd=None) -> subprocess.CompletedProcess:
    """The CLI's ``main`` in this process, answered as :func:`run_ham` answers: for the second
    and later commands of a test whose command is already run once in a subprocess elsewhere
    (a subprocess costs 3-4 s, most of it importing torch). The thread count and the working
    directory are restored after the call, and so are the registries
    (:func:`registries_restored`)."""
    from ham.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    threads = torch.get_num_threads()
    try:
        with registries_restored(), contextlib.chdir(cwd or os.getcwd()):
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                try:
                    rc = main(list(args))
                except SystemExit as exc:  # the parser's errors
                    rc = exc.code if isinstance(exc.code, int) else 1
    finally:
        torch.set_num_threads(threads)
    return subprocess.CompletedProcess(["ham", *args], rc, out.getvalue(), err.getvalue())


def ok(r: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    """``r`` after checking that the command succeeded (its stderr shown when not)."""
    assert r.returncode == 0, r.stderr
    return r


def one_line_error(r: subprocess.CompletedProcess) -> str:
    """The CLI's answer to bad input: exit 2, one line on stderr, no traceback."""
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ham: error: "), r.stderr
    return lines[0]


@pytest.fixture(scope="module")
def env():
    """The paper world online (the fast simulator), batches of 8, seed 0: one per test module."""
    from ham.learn.environment import HapticEnv
    from ham.world.config import WorldConfig
    from ham.world.source import make_source

    source, _ = make_source(None, WorldConfig())
    return HapticEnv(source, batch_size=8, seed=0)


@pytest.fixture(scope="module")
def small_table(tmp_path_factory) -> str:
    """A 9 x 9 glance table of the paper's world, built by the CLI: one per test module."""
    path = tmp_path_factory.mktemp("table") / "t.h5"
    ok(run_ham_inprocess("table", "build", "--grid", "9", "--out", str(path), "--quiet"))
    return str(path)


@pytest.fixture
def ham_cli():
    return run_ham


@pytest.fixture
def ham_main():
    """:func:`run_ham_inprocess`: the CLI in this process."""
    return run_ham_inprocess
