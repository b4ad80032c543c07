"""The one check of a device string (``cpu``, ``cuda``, ``cuda:N``) for every layer, and what
the CPU says of itself (:func:`cpu_info`)."""

from __future__ import annotations

import functools

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
