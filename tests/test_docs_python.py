"""Every Python block of the docs runs, each in a fresh interpreter (several register the same
object names), so the Python the docs show cannot drift from the package. The README's block
has its own test (tests/test_python_api.py). Two blocks are given what they name: a glance table
where docs/gym.md opens ``tables/paper.h5`` (a 3 x 3 one), and fewer training steps."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / "docs").glob("*.md"))

#: what a block needs to run here (a file it opens) or quickly (fewer steps), by the text it holds
SHORTER = {"steps=1500": "steps=4"}


def blocks() -> list[tuple[str, str]]:
    out = []
    for doc in DOCS:
        for i, code in enumerate(re.findall(r"```python\n(.*?)```", doc.read_text(), re.S)):
            out.append((f"{doc.name}:{i + 1}", code))
    return out


def test_the_docs_show_python():
    assert len(blocks()) >= 5


@pytest.mark.parametrize(("where", "code"), blocks(), ids=[w for w, _ in blocks()])
def test_a_python_block_of_the_docs_runs(tmp_path, where, code):
    for long, short in SHORTER.items():
        code = code.replace(long, short)
    if "tables/paper.h5" in code:
        from ham.world.config import WorldConfig
        from ham.world.table import build_table

        build_table(WorldConfig(), 3, tmp_path / "tables" / "paper.h5", progress=False)
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, f"{where}:\n{r.stderr[-2000:]}"
