"""Command-line options derived from the config dataclasses: one declaration per hyperparameter.

Each field of a config dataclass becomes ``--field-name``: its type from the annotation, its
accepted values from ``field(metadata={"choices": ...})`` (the same tuple the config validates
against), its help from the class docstring's ``Attributes:`` entry, and its default shown from the
dataclass. Options default to ``None`` ("not given"), so :func:`overrides` returns only what the
user typed and the dataclass keeps its own defaults and validation.

    add_config_options(parser, TrainConfig, skip={"model", "world", "table"})
    TrainConfig(**overrides(args, TrainConfig))
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import math
import re
import types
import typing
from collections.abc import Iterable

from ham.errors import HamError

#: Where each option's value goes: dest -> (config class, field name).
_DEST = "_config_options"


def _docstring_attributes(cls: type) -> dict[str, str]:
    """``name: text`` entries of a Google-style ``Attributes:`` section, continuation lines joined."""
    doc = inspect.getdoc(cls) or ""
    out: dict[str, str] = {}
    in_section, current = False, None
    for line in doc.splitlines():
        if line.strip() == "Attributes:":
            in_section = True
            continue
        if not in_section:
            continue
        if line and not line.startswith(" "):
            break
        m = re.match(r"^ {4}([A-Za-z_][\w, ]*):\s*(.*)$", line)
        if m:
            names = [n.strip() for n in m.group(1).split(",")]
            current = names
            for n in names:
                out[n] = m.group(2).strip()
        elif current and line.strip():
            for n in current:
                out[n] = f"{out[n]} {line.strip()}"
    return out


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def _base_type(annotation) -> type:
    """``int``, ``float``, ``bool`` or ``str`` behind ``X | None`` and friends."""
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union:
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        return _base_type(args[0]) if len(args) == 1 else str
    return annotation if annotation in (int, float, bool, str) else str


def _is_config(annotation) -> bool:
    """A nested config (``X`` or ``X | None`` with ``X`` a dataclass): its own options, not one."""
    args = typing.get_args(annotation) or (annotation,)
    return any(dataclasses.is_dataclass(a) for a in args)


def option_name(name: str) -> str:
    return "--" + name.replace("_", "-")


def add_config_options(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    cls: type,
    *,
    skip: Iterable[str] = (),
) -> list[str]:
    """Add one option per field of the dataclass ``cls`` (except ``skip`` and nested configs).

    Returns the option names added. Booleans get ``--x/--no-x``; numbers are checked finite.
    """
    skip = set(skip)
    hints = typing.get_type_hints(cls)
    docs = _docstring_attributes(cls)
    defaults = cls()
    added = []
    for f in dataclasses.fields(cls):
        if f.name in skip or _is_config(hints[f.name]):
            continue
        kind = _base_type(hints[f.name])
        default = getattr(defaults, f.name)
        text = docs.get(f.name, f.name.replace("_", " ")).replace("``", "")
        text = text.rstrip(".") + f" [default: {default}]"
        kwargs: dict = {"dest": f.name, "default": None, "help": text.replace("%", "%%")}
        choices = f.metadata.get("choices")
        if kind is bool:
            kwargs["action"] = argparse.BooleanOptionalAction
        else:
            kwargs["type"] = {int: _integer, float: _finite}.get(kind, str)
            kwargs["metavar"] = f.metadata.get("metavar") or (
                "{" + ",".join(choices) + "}" if choices else kind.__name__.upper()
            )
            # a registry (a dict: cores, policies) grows with --plugin after parsing: the
            # config checks those values, once the plugin has registered its names
            if choices and not isinstance(choices, dict):
                kwargs["choices"] = tuple(choices)
        parser.add_argument(option_name(f.name), **kwargs)
        added.append(f.name)
    # An argument group shares its parser's defaults: record which dests are config fields.
    registered = dict(parser.get_default(_DEST) or {})
    registered.update({name: cls for name in added})
    parser.set_defaults(**{_DEST: registered})
    return added


def overrides(args: argparse.Namespace, cls: type) -> dict:
    """The fields of ``cls`` the user gave on the command line (``None`` = not given)."""
    names = {f.name for f in dataclasses.fields(cls)}
    return {
        k: v
        for k, v in vars(args).items()
        if k in names and v is not None and k in (getattr(args, _DEST, None) or {})
    }


def given(args: argparse.Namespace) -> list[str]:
    """Every config option the user gave, as its flag (for "this option is ignored" errors)."""
    return [
        option_name(k)
        for k in (getattr(args, _DEST, None) or {})
        if getattr(args, k, None) is not None
    ]


def choices(cls: type, name: str) -> tuple[str, ...]:
    """The accepted values of field ``name`` of ``cls`` (its ``choices`` metadata)."""
    for f in dataclasses.fields(cls):
        if f.name == name:
            return tuple(f.metadata["choices"])
    raise HamError(f"{cls.__name__} has no field {name!r}")
