import os
import subprocess
import sys

import pytest
import torch

# Tests run on CPU with few threads: the CI machine has 2 cores.
torch.set_num_threads(1)


def run_ham(*args: str, cwd=None, timeout: float = 300) -> subprocess.CompletedProcess:
    """The real CLI in a subprocess."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, "-m", "ham", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=timeout,
    )


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


@pytest.fixture
def ham_cli():
    return run_ham
