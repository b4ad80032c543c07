"""Where the runs of an experiment live, and whether one is finished."""

from __future__ import annotations

import json
from pathlib import Path


def run_dir(root: Path, key: str) -> Path:
    return Path(root) / "runs" / key


def is_finished(out: Path, steps: int) -> bool:
    try:
        metrics = json.loads((out / "metrics.json").read_text())
    except (OSError, ValueError):
        return False
    return int(metrics.get("steps", -1)) >= steps
