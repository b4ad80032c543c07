"""The held-out bisection's table: evaluations and transfer.py's lines, by code version.

python docs/results/next_world/held_out/summarize.py RUNS_DIR OUT_DIR

RUNS_DIR holds, per code version V and seed S, V_sS.train.json and V_sS.test.json (`ham evaluate
RUN --batches 50 --seed 12345 [--objects composite:test] --json`) and transfer.jsonl (transfer.py's
lines for the runs V_sS); OUT_DIR gets summary.json and table.md (mean ± s.e.m. over the seeds).
"""

import argparse
import json
import re
from pathlib import Path

from ham.experiments.reproduce import format_mean_sem, mean_sem

NAME = re.compile(r"^(?P<version>.+)_s(?P<seed>\d+)$")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("runs_dir", type=Path)
    ap.add_argument("out_dir", type=Path)
    args = ap.parse_args()
    # versions in the order of transfer.jsonl's lines (the bisection's, oldest first)
    rows: dict[str, dict[str, list[float]]] = {}
    for line in (args.runs_dir / "transfer.jsonl").read_text().splitlines():
        t = json.loads(line)
        name = Path(t["run"]).name
        r = rows.setdefault(NAME.match(name)["version"], {})
        for split in ("train", "test"):
            e = json.loads((args.runs_dir / f"{name}.{split}.json").read_text())
            r.setdefault(f"eval {split}", []).append(e["accuracy"])
        for part in ("random", "policy", "classifier"):
            for g in ("2", "6"):
                r.setdefault(f"{part} {g}", []).append(t[part][g])
    summary = {v: {k: mean_sem(xs) for k, xs in r.items()} for v, r in rows.items()}
    args.out_dir.mkdir(parents=True, exist_ok=True)
    (args.out_dir / "summary.json").write_text(
        json.dumps({"values": rows, "mean_sem_n": summary}, indent=1) + "\n"
    )
    cols = list(next(iter(rows.values())))
    lines = ["| code | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for v, s in summary.items():
        lines.append(f"| {v} | " + " | ".join(format_mean_sem(*s[c]) for c in cols) + " |")
    (args.out_dir / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
