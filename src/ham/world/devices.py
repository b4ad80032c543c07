"""The one check of a device string (``cpu``, ``cuda``, ``cuda:N``) for every layer, what the
CPU says of itself (:func:`cpu_info`), and what a result was computed with: the code's commit
and the machine (:func:`environment_record`, kept beside every run's and report's numbers)."""

from __future__ import annotations

import functools
import os
from pathlib import Path

import torch

from ham.errors import HamError

DEVICE_TYPES: tuple[str, ...] = ("cpu", "cuda")


def check_device(device: str | torch.device, *, available: bool = True) -> torch.device:
    """``device`` as a :class:`torch.device`, or a one-line :class:`HamError` naming it.

    Accepted: ``cpu`` and ``cuda`` / ``cuda:N``. With ``available`` (the default) CUDA must also
    be present with device ``N``; without, only the spelling is checked (a saved config may name
    a GPU that this machine lacks, and be overridden with ``--device cpu``).
    """
    accepted = "cpu, cuda or cuda:N"
    if not isinstance(device, (str, torch.device)):
        raise HamError(f"device {device!r}; accepted: {accepted}")
    try:
        d = torch.device(device)
    except (RuntimeError, ValueError, TypeError):
        raise HamError(f"device {str(device)!r}; accepted: {accepted}") from None
    if d.type not in DEVICE_TYPES or (d.type == "cpu" and d.index not in (None, 0)):
        raise HamError(f"device {str(device)!r}; accepted: {accepted}")
    if available and d.type == "cuda":
        if not torch.cuda.is_available():
            raise HamError(
                f"device {str(device)!r}: CUDA is not available on this machine; accepted: cpu"
            )
        n = torch.cuda.device_count()
        if d.index is not None and d.index >= n:
            raise HamError(
                f"device {str(device)!r}: this machine has {n} CUDA device(s); accepted: "
                f"cuda:0..cuda:{n - 1}"
            )
    return d


def cpu_info(key: str) -> str:
    """The first ``key`` line of ``/proc/cpuinfo`` (``vendor_id``: ``GenuineIntel`` or
    ``AuthenticAMD``; ``model name``; ``flags``), or ``""`` where there is none (another OS or
    architecture)."""
    return _first_cpu_lines().get(key, "")


@functools.cache
def _first_cpu_lines() -> dict[str, str]:
    """The first CPU's ``/proc/cpuinfo`` lines by name, read once per process (the CPU does not
    change under a running process)."""
    lines: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                name, sep, value = line.partition(":")
                if sep:
                    lines.setdefault(name.strip(), value.strip())
                elif lines:  # the blank line after the first CPU's block
                    break
    except OSError:
        pass
    return lines


@functools.cache
def source_commit() -> str | None:
    """The git commit of the ``ham`` source this process runs (``+dirty`` when tracked files
    differ from it), or ``None`` where this file is not a checkout's tracked file (an installed
    wheel, also one inside a checkout's venv): which code made a result, beside its numbers.

    Asked once a process: runs, grids and reproductions ask it when they start (the code they
    loaded), so a commit made while a long run goes on is not named for it at its end."""
    import subprocess

    here = Path(__file__).resolve().parent

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(
                ["git", "-C", str(here), *args], capture_output=True, text=True, timeout=10
            )
        except (OSError, subprocess.SubprocessError):  # no git, or it hung
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    # a copy installed into a venv inside some checkout is not that checkout's code
    if git("ls-files", "--error-unmatch", Path(__file__).name) is None:
        return None
    commit = git("rev-parse", "--short=12", "HEAD")
    if not commit:
        return None
    dirty = git("status", "--porcelain", "--untracked-files=no", "--", str(here.parent))
    return commit + ("+dirty" if dirty else "")


def environment_record() -> dict:
    """What the results were computed with (the code's version and commit, the machine),
    kept beside them."""
    import platform

    import numpy as np

    import ham

    cpu = cpu_info("model name") or platform.processor() or platform.machine()
    return {
        "ham": ham.__version__,
        "commit": source_commit() or "unknown (no git checkout, or no git)",
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": np.__version__,
        "platform": platform.platform(),
        "cpu": cpu,
        # what decides the last bits of the numbers on a CPU (docs/results: "The same numbers on
        # another machine"): PyTorch's kernels and MKL's reproducible mode, if set
        "simd": getattr(torch.backends.cpu, "get_cpu_capability", lambda: "unknown")(),
        "MKL_CBWR": os.environ.get("MKL_CBWR", "unset"),
        "cores": os.cpu_count(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none",
    }
