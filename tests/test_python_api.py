"""The README's "From Python" block runs as written (the real table build, training, checkpoint
and evaluation), so the Python API the README shows cannot drift from the package."""

import contextlib
import io
import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _block() -> str:
    text = README.read_text()
    section = text[text.index("### From Python") :]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_readmes_python_block_runs(tmp_path):
    out = io.StringIO()
    with contextlib.chdir(tmp_path), contextlib.redirect_stdout(out):
        exec(compile(_block(), "README.md", "exec"), {"__name__": "readme"})
    lines = out.getvalue().splitlines()
    assert len(lines) == 2, lines
    best = float(lines[0].split()[0])
    assert 0.0 <= best <= 1.0
    assert lines[1].endswith("['box', 'ramp_up', 'convex', 'ramp_down']"), lines[1]
    run = tmp_path / "runs" / "py" / "run"
    assert (run / "checkpoint.pt").exists() and (run / "metrics.json").exists()
    assert (tmp_path / "runs" / "py" / "table_21.h5").exists()
