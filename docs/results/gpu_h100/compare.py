"""Two `ham reproduce` folders of the same grid (eager, and --cuda-graph): the largest
difference in any run's evaluation accuracy, and each folder's Table 1 rows."""

import json
import sys
from pathlib import Path

a, b = Path(sys.argv[1]), Path(sys.argv[2])
worst, n = 0.0, 0
for m in sorted((a / "runs").glob("*/metrics.json")):
    other = b / "runs" / m.parent.name / "metrics.json"
    if not other.exists():
        print("missing", other)
        continue
    x, y = json.loads(m.read_text()), json.loads(other.read_text())
    ax, ay = ([h["accuracy"] for h in r["history"]] for r in (x, y))
    worst = max(worst, max(abs(p - q) for p, q in zip(ax, ay, strict=True)))
    n += 1
print(
    f"{n} runs compared; largest accuracy difference in any evaluation, eager vs graph: {worst:.4f}"
)
for d in (a, b):
    r = (d / "report.md").read_text() if (d / "report.md").exists() else ""
    print(d, [ln for ln in r.splitlines() if ln.startswith(("| 3 |", "| 10 |"))])
