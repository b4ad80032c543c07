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


@pytest.fixture
def ham_cli():
    return run_ham
