"""``ham train``, ``ham evaluate``, ``ham heatmap``: the agent's subcommands.

``ham.cli.main`` adds them through :func:`add_commands`; each command returns an exit code and raises
:class:`ham.errors.HamError` for anything the user got wrong (printed as one line by ``ham.cli.main``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

from ham.errors import HamError

PAPER_PARAMETERS = 741_248


def add_commands(subparsers) -> None:
    """Add ``train``, ``evaluate`` and ``heatmap`` to an argparse subparsers object."""
    from ham.cli.config_args import add_config_options, choices
    from ham.learn.ap_adapter import ACTIONS, GLIMPSES
    from ham.learn.train import TrainConfig
    from ham.model.agent import HamConfig

    p = subparsers.add_parser(
        "train",
        help="train a Haptic Attention Model (hybrid REINFORCE), or --resume one",
        description="Train a HAM on fresh batches of objects. Glances come from a glance table "
        "(--table FILE, the paper's nearest grid point) or, by default, online from the fast "
        "simulator (--online: exact poses, no grid). Writes DIR/config.json, DIR/metrics.json, "
        "DIR/checkpoint.pt and TensorBoard scalars in DIR/tb.",
    )
    # Every hyperparameter once: the options come from TrainConfig and HamConfig themselves.
    hyper = p.add_argument_group("training (TrainConfig; paper defaults)")
    add_config_options(hyper, TrainConfig, skip={"model", "world", "table", "env"})
    net = p.add_argument_group("network (HamConfig; paper defaults)")
    add_config_options(
        net,
        HamConfig,
        skip={"n_objects", "pressure_dim", "pose_dims", "moves", "move_length", "plugin"},
    )
    net.add_argument("--plugin", metavar="FILE.py",
                     help="a Python file that registers your own cores, location policies or "
                     "learners (ham.model.core.register_core, ham.model.policy.register_policy, "
                     "ham.learn.learners.register_learner) for --core/--policy/--learner; the "
                     "run records its text (docs/agent.md, docs/learners.md)")  # fmt: skip
    src = p.add_mutually_exclusive_group()
    src.add_argument("--table", metavar="FILE", help="glance table (HDF5) to look glances up in")
    src.add_argument("--online", action="store_true",
                     help="simulate glances online with the fast simulator (the default)")  # fmt: skip
    src.add_argument("--env", metavar="ap_gym:ENV_ID",
                     help="train on an ap_gym active classification environment (docs/gym.md)")  # fmt: skip
    p.add_argument("--actions", choices=ACTIONS,
                   help="with --env: poses are targets (default) or movements")  # fmt: skip
    p.add_argument("--max-step-length", metavar="L",
                   help="with --env: image env step length, a number or 'teleport'")  # fmt: skip
    p.add_argument("--glimpse", choices=GLIMPSES,
                   help="with --env: the glimpse as is (flat, default) or minus its mean "
                   "(centered; with --normalization none)")  # fmt: skip
    p.add_argument("--eval-env", metavar="ap_gym:ENV_ID",
                   help="with --env: evaluation environment (default: the training one)")  # fmt: skip
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", metavar="DIR", help="run directory to create")
    p.add_argument("--resume", metavar="DIR", help="continue the run in DIR from its checkpoint")
    _add_world_options(p)
    p.set_defaults(func=cmd_train)

    p = subparsers.add_parser("evaluate", help="evaluate a trained HAM on fresh balanced batches")
    p.add_argument("run", metavar="DIR", help="run directory (from ham train)")
    p.add_argument("--batches", type=int, default=100, help="balanced batches (default 100)")
    p.add_argument("--seed", type=int, default=12345, help="seed of the poses (default 12345)")
    p.add_argument("--device", help="cpu or cuda (default: the run's)")
    p.add_argument("--eval-policy", choices=choices(TrainConfig, "eval_policy"),
                   help="location policy: mean poses or sampled (default: the run's)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--objects", metavar="SET",
                   help="evaluate on other objects, one per class in the run's class order "
                   "(e.g. composite:test for a run trained on composite:train: held-out "
                   "instances); online runs only")  # fmt: skip
    _add_table_options(p)
    p.add_argument("--confusion", metavar="PNG",
                   help="also plot the confusion matrix after the last glance")  # fmt: skip
    p.add_argument("--swap-last-pose", action="store_true",
                   help="also the accuracy with the last glance made at another episode's pose: "
                   "one of the same object, one of another object, a uniform one (how much the "
                   "pose itself tells the classifier)")  # fmt: skip
    p.set_defaults(func=cmd_evaluate)

    p = subparsers.add_parser(
        "heatmap", help="heat map of the last glance's pose per object, with the learned means"
    )
    p.add_argument("run", metavar="DIR", help="run directory (from ham train)")
    p.add_argument("--out", required=True, metavar="PNG", help="image to write")
    p.add_argument("--batches", type=int, default=1000, help="balanced batches (default 1000)")
    p.add_argument("--bins", type=int, default=20, help="bins per axis (default 20)")
    p.add_argument("--seed", type=int, default=12345, help="seed of the poses (default 12345)")
    p.add_argument("--device", help="cpu or cuda (default: the run's)")
    p.add_argument("--eval-policy", choices=choices(TrainConfig, "eval_policy"),
                   help="location policy: mean poses or sampled (default: the run's)")  # fmt: skip
    p.add_argument("--json", metavar="FILE", help="also write the heat map data as JSON")
    p.add_argument("--objects", metavar="SET",
                   help="on other objects, one per class in the run's class order (e.g. "
                   "composite:test); online runs only")  # fmt: skip
    _add_table_options(p)
    p.set_defaults(func=cmd_heatmap)


def _add_table_options(p: argparse.ArgumentParser) -> None:
    """``evaluate``'s and ``heatmap``'s glance tables (:func:`_load` reads them)."""
    p.add_argument("--table", metavar="FILE",
                   help="the run's glance table at a new path (accepted only with the sha256 "
                   "the run's checkpoint kept)")  # fmt: skip
    p.add_argument("--transfer-table", metavar="FILE",
                   help="the agent on the glances of another table of the same objects and pose "
                   "dims (another simulator, read-out, sensor or grid): how what the run learned "
                   "transfers; prints how that world differs from the run's")  # fmt: skip


def _add_world_options(p: argparse.ArgumentParser) -> None:
    try:
        from ham.cli.options import add_world_options
    except ImportError:  # pragma: no cover - ham.cli.main is part of the package
        return
    add_world_options(p)


def _world_from_args(args: argparse.Namespace):
    from ham.cli.options import world_from_args

    return world_from_args(args)


def _config_from_args(args: argparse.Namespace):
    from ham.cli.config_args import overrides
    from ham.learn.train import TrainConfig, model_for_source
    from ham.model.agent import HamConfig
    from ham.world.config import WorldConfig

    world = _world_from_args(args)
    if args.steps is not None and args.env_steps is not None:
        raise HamError(f"--steps {args.steps} and --env-steps {args.env_steps} both set the "
                       "training length; give one of them")  # fmt: skip
    if args.table and args.objects is not None:
        raise HamError(f"--objects {args.objects!r} chooses the online world's objects; the table "
                       f"{args.table!r} has its own: give one of them")  # fmt: skip
    if args.table:
        from ham.world.table import table_info

        if not Path(args.table).exists():
            raise HamError(f"glance table {args.table!r} does not exist")
        info = table_info(args.table)
        _check_table_sensor(args, info)
        # Register the table's recorded objects file now: a conflict fails before DIR is made.
        WorldConfig.from_dict(info.world)
    if args.env and args.objects is not None:  # even the default set: it would be ignored
        raise HamError(f"--objects {args.objects!r} chooses the haptic world's objects; --env "
                       f"{args.env} brings its own classes: leave --objects out")  # fmt: skip
    if args.env:
        from ham.cli.options import sensor_changes_from_args

        if sensor_changes_from_args(args):
            raise HamError(
                f"--taxels/--pitch set the haptic world's pad; --env {args.env} brings its own "
                "glimpse: leave them out"
            )
    _refuse_world_options(args)  # --table and --env bring their own world: nothing is ignored
    table = str(Path(args.table).resolve()) if args.table else None
    train_changes = overrides(args, TrainConfig)
    preset = _preset_defaults(args, world)
    if preset is not None:
        table = table or preset.get("table")
        train_changes.setdefault("eval_policy", preset["eval_policy"])
    # The input size (taxels^2) and the classes come from the table or the online world.
    model = HamConfig(**overrides(args, HamConfig), plugin=_plugin_from_args(args))
    model = model_for_source(model, table, world)
    config = TrainConfig(model=model, table=table, world=world, **train_changes)
    if not args.env:
        stray = [f"--{k.replace('_', '-')}" for k in ("actions", "max_step_length", "eval_env", "glimpse")
                 if getattr(args, k) is not None]  # fmt: skip
        if stray:
            raise HamError(f"{', '.join(stray)} apply only with --env ap_gym:ENV_ID")
    else:  # another world (docs/gym.md): the model sized for its glimpse and classes
        from ham.cli.envs import parse_max_step_length
        from ham.learn.ap_adapter import ApGymConfig
        from ham.learn.train import fit_to_ap_gym

        env = ApGymConfig(
            args.env,
            eval_env=args.eval_env,
            actions=args.actions or "absolute",
            max_step_length=parse_max_step_length(args.max_step_length),
            glimpse=args.glimpse or "flat",
        )
        config = fit_to_ap_gym(config, env)
    return config


def _plugin_from_args(args: argparse.Namespace) -> dict | None:
    """The record of ``--plugin FILE.py`` (None without); HamConfig runs it."""
    if args.plugin is None:
        return None
    from ham.model.plugin import read_plugin

    return read_plugin(args.plugin)


def _preset_defaults(args: argparse.Namespace, world) -> dict | None:
    """With ``--world PRESET``: the preset's evaluation policy and, unless ``--online`` or
    ``--env``, its glance table (of ``world``, at the preset's grid), built once into the cache."""
    from ham.cli.options import command_line, preset_from_args

    preset = preset_from_args(args)
    if preset is None:
        return None
    if (args.online or args.env) and args.cache_dir is not None:
        raise HamError(
            f"--cache-dir {args.cache_dir!r} with {'--online' if args.online else '--env'}: no "
            "glance table is used; accepted: --cache-dir with a table-backed --world run"
        )
    if not (args.online or args.env):
        from ham.world.cache import cached_table

        path = cached_table(world, preset["grid"], args.cache_dir,
                            progress=not args.no_progress, command=command_line(args))  # fmt: skip
        preset["table"] = str(path.resolve())
    return preset


def _check_table_sensor(args: argparse.Namespace, info) -> None:
    """With --table the table's recorded sensor rules: refuse a --taxels/--pitch that differs."""
    from ham.cli.options import sensor_changes_from_args

    for key, value in sensor_changes_from_args(args).items():
        if info.sensor.get(key) != value:
            raise HamError(
                f"--{key} {value} but glance table {args.table!r} was recorded with {key} = "
                f"{info.sensor.get(key)}; accepted: the table's sensor (or leave --{key} out)"
            )


def _refuse_world_options(args: argparse.Namespace) -> None:
    """World options with --table, --env or --resume would be silently ignored: refuse them."""
    from ham.world.config import WorldConfig

    owner = (
        f"--table {args.table}" if args.table else f"--env {args.env}" if args.env
        else f"--resume {args.resume}" if args.resume else None
    )  # fmt: skip
    if owner is None:
        return
    world = _world_from_args(args)
    if world != WorldConfig():
        raise HamError(
            f"{owner} brings its own world; remove the world options "
            f"({', '.join(_world_changes(world))})"
        )


def _world_changes(world) -> list[str]:
    """``key=value`` for each field of ``world`` that differs from the default world."""
    from ham.world.config import WorldConfig

    def flat(d: dict, prefix: str = "") -> dict:
        out = {}
        for k, v in d.items():
            out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
        return out

    d = world.to_dict()
    for key in ("objects_file", "simulator_file"):  # name the file, not its recorded text
        if d.get(key):
            d[key] = d[key]["name"]
    new, old = flat(d), flat(WorldConfig().to_dict())
    return [f"{k}={v!r}" for k, v in new.items() if old.get(k, object()) != v]


@contextlib.contextmanager
def _diverged(out: Path):
    """A run that diverged, with what its folder keeps and what to do: resuming repeats the same
    numbers (the same seed from the same checkpoint), so it would diverge again."""
    from ham.learn.train import DivergedError

    try:
        yield
    except DivergedError as exc:
        if exc.saved_step is None:  # nothing kept
            raise
        raise HamError(
            f"{exc}; {str(out)!r} keeps the run as saved at step {exc.saved_step} (resuming "
            f"diverges again); accepted: a fresh run in another --out (or with {str(out)!r} "
            "removed), e.g. with a smaller --lr"
        ) from None


def cmd_train(args: argparse.Namespace) -> int:
    from ham.cli.options import set_threads
    from ham.learn.train import resume, train

    set_threads(args.threads)
    progress = not args.no_progress
    if args.resume:
        if args.out:
            raise HamError("give either --resume DIR or --out DIR, not both")
        from ham.cli.config_args import given

        ignored = [flag for flag in given(args) if flag not in ("--steps", "--env-steps")]
        ignored += [
            f"--{k.replace('_', '-')}"
            for k in (
                "env",
                "actions",
                "max_step_length",
                "eval_env",
                "glimpse",
                "taxels",
                "pitch",
                "objects",
                "objects_file",
                "simulator_file",
                "plugin",
            )  # fmt: skip
            if getattr(args, k, None) is not None
        ]
        if ignored:
            raise HamError(
                f"--resume continues the run with its own config; remove {', '.join(ignored)} "
                "(only --steps or --env-steps may change, and --table may name its moved table)"
            )
        _refuse_world_options(args)  # the run brings its own world
        out = Path(args.resume)
        if args.steps is not None and args.env_steps is not None:
            raise HamError("give --steps or --env-steps to --resume, not both")
        with _diverged(out):
            metrics = resume(out, steps=args.steps, env_steps=args.env_steps,
                             progress=progress, table=args.table)  # fmt: skip
    else:
        if not args.out:
            raise HamError("ham train needs --out DIR (or --resume DIR)")
        from ham.world.devices import check_device
        from ham.world.files import check_output_dir

        out = check_output_dir(args.out)
        config = _config_from_args(args)
        check_device(config.device)  # before any output: a missing GPU is named at once
        from ham.model.agent import HapticAttentionModel, count_parameters

        n = count_parameters(HapticAttentionModel(config.model))
        print(
            f"HAM: {n:,} trainable weights (the paper reports {PAPER_PARAMETERS:,}; "
            "see docs/agent.md)",
            flush=True,
        )
        with _diverged(out):
            metrics = train(config, out, progress=progress)
    _print_summary(metrics, out)
    from ham.experiments.figures import plot_training_curve

    print(f"wrote {plot_training_curve(metrics, out / 'training_curve.png')}")
    return 0


def _print_summary(metrics: dict, out: Path) -> None:
    per = ", ".join(f"{a:.3f}" for a in metrics["accuracy_per_glance"] or [])
    print(
        f"{out}: {metrics['steps']} steps; final accuracy {metrics['final_accuracy']:.4f}, "
        f"best {metrics['best_accuracy']:.4f} (step {metrics['best_step']}); per glance [{per}]"
    )


def _load(args: argparse.Namespace):
    """The run of ``evaluate``/``heatmap``: DIR with its --device, --objects, --table and
    --transfer-table."""
    from ham.learn.train import load_run

    return load_run(args.run, device=args.device, objects=args.objects, table=args.table,
                    transfer_table=args.transfer_table)  # fmt: skip


def cmd_evaluate(args: argparse.Namespace) -> int:
    from ham.learn.evaluation import check_swappable, evaluate, last_pose_swap

    if args.confusion:  # refused before the evaluation runs, not after
        from ham.world.files import check_output

        check_output(args.confusion, (".png",), what="--confusion")
    run = _load(args)
    policy = args.eval_policy or run.config.eval_policy
    try:
        if args.swap_last_pose:  # refused before the evaluation's minutes, not after
            check_swappable(run.env)
        result = evaluate(
            run.agent, run.env, args.batches, seed=args.seed, policy=policy, progress=True
        )
        swap = None
        if args.swap_last_pose:
            swap = last_pose_swap(
                run.agent, run.env, args.batches, seed=args.seed, policy=policy, progress=True
            )
    finally:
        run.close()
    d = {"run": str(args.run), "steps": run.step, "eval_policy": policy, **result.to_dict()}
    if swap is not None:
        d["last_pose_swap"] = swap
    if run.transfer is not None:
        d["transfer_table"], d["transfer_differences"] = run.config.table, run.transfer
    if args.confusion:
        from ham.experiments.figures import plot_confusion

        title = f"{args.run}: step {run.step}, after glance {len(result.confusion)}"
        d["confusion_png"] = str(
            plot_confusion(result.confusion[-1], result.objects, args.confusion, title=title)
        )
    if args.json:
        json.dump(d, sys.stdout)
        sys.stdout.write("\n")
        return 0
    print(
        f"{args.run}: step {run.step}, {result.episodes} episodes ({result.batches} balanced "
        f"batches), {policy} poses"
    )
    if run.transfer is not None:
        print(f"glances from {run.config.table} (its world against the run's: "
              f"{'; '.join(run.transfer) or 'no difference'})")  # fmt: skip
    # pose spread: the std of the poses over the episodes (within: the same per true object)
    print(
        f"{'glance':>6}  {'accuracy':>8}  {'accumulated':>11}  {'pose spread':>11}  {'within':>6}"
    )
    for s, row in enumerate(
        zip(
            result.accuracy_per_glance,
            result.accumulated_accuracy_per_glance,
            result.pose_spread,
            result.pose_spread_within_object,
            strict=True,
        )
    ):
        print(f"{s + 1:>6}  {row[0]:>8.4f}  {row[1]:>11.4f}  {row[2]:>11.3f}  {row[3]:>6.3f}")
    print(f"accuracy after the last glance: {result.accuracy:.4f}")
    _print_confusion(result.confusion[-1], result.per_object_accuracy, result.objects)
    if swap is not None:
        print(
            "the last glance at another pose, accuracy: own {own:.4f}, another episode of the "
            "same object's {same_object:.4f}, another object's {other_object:.4f}, uniform "
            "{uniform:.4f}".format(**swap)
        )
    if args.confusion:
        print(f"wrote {d['confusion_png']}")
    return 0


def _print_confusion(confusion: list, per_object: list, objects: list[str]) -> None:
    """Per object after the last glance: episodes, accuracy, and its row of the confusion matrix."""
    w = max(8, *(len(o) for o in objects))
    print("after the last glance, per true object (columns: predicted):")
    print(
        f"{'object':<{w}}  {'episodes':>8}  {'accuracy':>8}  "
        + "  ".join(f"{o:>{w}}" for o in objects)
    )
    for name, row, acc in zip(objects, confusion, per_object, strict=True):
        a = "-" if acc is None else f"{acc:.4f}"
        print(f"{name:<{w}}  {sum(row):>8}  {a:>8}  " + "  ".join(f"{c:>{w}}" for c in row))


def cmd_heatmap(args: argparse.Namespace) -> int:
    from ham.experiments.figures import plot_heatmap
    from ham.learn.evaluation import heatmap_data
    from ham.world.files import check_output, write_text

    check_output(args.out, (".png",))
    if args.json:
        check_output(args.json, (".json",), what="--json")
    run = _load(args)
    policy = args.eval_policy or run.config.eval_policy
    data = heatmap_data(
        run.agent, run.env, args.batches, args.bins, seed=args.seed, policy=policy, progress=True
    )
    data["step"] = run.step
    if run.transfer is not None:
        data["transfer_table"], data["transfer_differences"] = run.config.table, run.transfer
    out = plot_heatmap(data, args.out)
    if args.json:
        text = json.dumps(data) + "\n"
        write_text(args.json, text, what="heat map data")
    where = "" if run.transfer is None else f" on the glances of {run.config.table}"
    print(f"wrote {out} (accuracy {data['accuracy']:.4f} over {args.batches} batches{where})")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m ham.cli.agent``), the same as ``ham <command>``."""
    parser = argparse.ArgumentParser(prog="ham")
    add_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except HamError as exc:
        print(f"ham: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
