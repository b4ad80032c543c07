"""What checking a simulator file's glances costs: the checked glance against the unchecked one.

Every glance of a registered simulator (a simulator file's, e.g. docs/plugins/binary_pad.py) is
checked by :class:`ham.world.simulators.CheckedSimulator`: every field's shape, dtype, device and
values. This times ``CheckedSimulator.glance`` against the same simulator's own ``glance`` on the
same batch, interleaved pair by pair in one process (the machine's load drifts alike for both),
and prints the median times and the median ratio. The batch is a 201 x 201 table's object, as
``ham table build`` glances it.

    .venv/bin/python benchmarks/bench_checked_glance.py [--batch 40401] [--repeats 9] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

from ham.world.config import WorldConfig, make_simulator
from ham.world.simulators import load_simulator_file, read_simulator_file

PAD = Path(__file__).resolve().parents[1] / "docs/plugins/binary_pad.py"


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=201 * 201, help="glances a call (40401)")
    parser.add_argument("--repeats", type=int, default=9, help="timed pairs (9)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    record = read_simulator_file(PAD)
    load_simulator_file(record)
    sim = make_simulator(WorldConfig(simulator="binary", simulator_file=record))
    g = torch.Generator().manual_seed(0)
    ids = torch.randint(0, 4, (args.batch,), generator=g)
    q_x, q_phi = (torch.rand(args.batch, generator=g) * 2 - 1 for _ in range(2))
    sim.glance(ids[:8], q_x[:8], q_phi[:8])  # the one-time repeat check, out of the timing
    checked, own = [], []
    for _ in range(args.repeats):
        t = time.perf_counter()
        sim.glance(ids, q_x, q_phi)
        checked.append(time.perf_counter() - t)
        t = time.perf_counter()
        sim.inner.glance(ids, q_x, q_phi)
        own.append(time.perf_counter() - t)
    result = {
        "batch": args.batch,
        "repeats": args.repeats,
        "checked_ms": 1e3 * statistics.median(checked),
        "unchecked_ms": 1e3 * statistics.median(own),
        "ratio": statistics.median(a / b for a, b in zip(checked, own, strict=True)),
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(
            f"{args.batch} glances a call, {args.repeats} pairs: checked "
            f"{result['checked_ms']:.1f} ms, the simulator's own {result['unchecked_ms']:.1f} ms, "
            f"ratio {result['ratio']:.3f}"
        )
    return result


if __name__ == "__main__":
    main()
