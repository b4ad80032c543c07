"""``ham baselines``: exact accuracies of reference policies on a glance table
(:mod:`ham.learn.planners`): how far from optimal is a learned policy?"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ham.errors import HamError


def add_commands(subparsers) -> None:
    from ham.learn.planners import FIRST, POLICIES

    p = subparsers.add_parser(
        "baselines",
        help="exact accuracy of random, grid, infogain and oracle policies on a glance table",
        description="Bayes accuracy after G glances of a reference policy on a glance table, "
        "computed exactly (dynamic programming over consistent object sets): random poses, a "
        "fixed grid sweep, greedy expected information gain, or the optimal planner (with N*, "
        "the fewest expected glances that identify the object).",
    )
    p.add_argument("--policy", required=True, choices=POLICIES, help="the reference policy")
    p.add_argument("--table", required=True, metavar="FILE", help="glance table (HDF5)")
    p.add_argument("--glances", type=int, nargs="+", default=[1, 2, 3, 4, 6, 8, 10],
                   metavar="G", help="glance counts (default 1 2 3 4 6 8 10)")  # fmt: skip
    p.add_argument("--first", choices=FIRST, default="planned",
                   help="planned (default) or random: the first glance uniform, as the HAM's")  # fmt: skip
    p.add_argument("--tolerance", type=float, default=1e-6,
                   help="images closer than this (L2, normalized) are equal (default 1e-6)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_baselines)


def cmd_baselines(args: argparse.Namespace) -> int:
    from ham.learn.planners import Partitions, Planner
    from ham.world.table import GlanceTable

    for g in args.glances:
        if g < 1:
            raise HamError(f"--glances {g}; accepted: integers >= 1")
    if not Path(args.table).is_file():
        raise HamError(f"glance table {args.table!r} does not exist")
    if args.first == "random" and args.policy in ("random", "grid"):
        raise HamError(f"--first random applies to infogain and oracle, not to {args.policy!r}")
    table = GlanceTable.load(args.table)
    planner = Planner(Partitions.from_table(table, args.tolerance))
    accuracy = {str(g): planner.accuracy(args.policy, g, args.first) for g in args.glances}
    result = {
        "policy": args.policy,
        "table": str(args.table),
        "objects": table.objects,
        "first": args.first,
        "tolerance": args.tolerance,
        "distinct_actions": int(len(planner.parts.labels)),
        "accuracy": accuracy,
    }
    if args.policy in ("oracle", "infogain"):
        result["expected_glances_to_identify"] = planner.expected_glances(args.policy, args.first)
    if args.json:
        json.dump(result, sys.stdout)
        sys.stdout.write("\n")
        return 0
    print(
        f"{args.policy} on {args.table} ({len(table.objects)} objects, "
        f"{result['distinct_actions']} distinct pose actions, first glance {args.first})"
    )
    print("| glances | accuracy |\n|---|---|")
    for g, a in accuracy.items():
        print(f"| {g} | {a:.4f} |")
    if "expected_glances_to_identify" in result:
        print(f"expected glances to identify: {result['expected_glances_to_identify']:.3f}")
    return 0
