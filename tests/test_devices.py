"""``ham.world.devices.cpu_info``: the first CPU's ``/proc/cpuinfo`` lines, which pick the
batched model's CPU product path (``ham.learn.stacked_ham``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ham.world.devices import cpu_info

CPUINFO = Path("/proc/cpuinfo")


@pytest.mark.skipif(not CPUINFO.exists(), reason="no /proc/cpuinfo on this OS")
def test_cpu_info_reads_the_first_cpu_block() -> None:
    first = CPUINFO.read_text().split("\n\n")[0]
    lines = dict(
        (name.strip(), value.strip())
        for name, sep, value in (line.partition(":") for line in first.splitlines())
        if sep
    )
    for key in ("vendor_id", "model name", "flags"):
        assert cpu_info(key) == lines.get(key, "")
    assert cpu_info("no such key") == ""
