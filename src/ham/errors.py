"""One exception type for every error a user can cause: bad input, a bad file, a bad config.

The CLI prints its message on one line and exits non-zero, without a traceback.
"""

import dataclasses
import functools
import inspect
import math
import numbers
import os
import re
import types
import typing
from collections.abc import Iterable


class HamError(ValueError):
    """A user-facing error whose message names the bad value and what is accepted.

    Its message is one line: a value whose repr spans lines (a NumPy array's) is joined."""

    def __init__(self, message: object = "", *args: object) -> None:
        if isinstance(message, str) and "\n" in message:
            message = " ".join(message.split())
        super().__init__(message, *args)


def brief(value: object) -> str:
    """``repr(value)`` for a message, but an array or tensor of more than 4 values by its shape
    and dtype (a batch of 64 poses is not worth printing) and a dict whose repr is over 80
    characters by its keys. Numbers and text stay whole: the message names the value."""
    shape, dtype = getattr(value, "shape", None), getattr(value, "dtype", None)
    if isinstance(shape, tuple) and dtype is not None and math.prod(shape) > 4:
        return f"an array of shape {tuple(shape)} and dtype {dtype}"
    text = repr(value)
    if isinstance(value, dict) and len(text) > 80:
        return f"a dict with keys {sorted(map(str, value))}"
    return text


_NEW_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")


def check_new_name(kind: str, name: object, taken) -> None:
    """``name`` for a new entry of the registry of ``kind`` ("simulator", "learner"): letters,
    digits and ``_ . -``, and none of ``taken``."""
    if not (isinstance(name, str) and _NEW_NAME.match(name)):
        raise HamError(f"{kind} name {name!r}; accepted: letters, digits and _ . - (not empty)")
    if name in taken:
        raise HamError(f"{kind} {name!r} is registered already; accepted: another name")


def check_choices(config) -> None:
    """Every field of the dataclass ``config`` declared with ``metadata={"choices": ...}`` holds
    one of them: the one list of accepted values, which the CLI offers too."""
    import dataclasses

    for f in dataclasses.fields(config):
        allowed = f.metadata.get("choices")
        if allowed is not None and getattr(config, f.name) not in allowed:
            value = getattr(config, f.name)
            raise HamError(f"{f.name} = {value!r}; accepted: {', '.join(allowed)}")


class DivergedError(HamError):
    """Training met NaN or inf: in the loss, or in the weights after an update (raised by the
    learn layer's loops, :mod:`ham.learn.train`, and its learners', :mod:`ham.learn.off_policy`).

    ``saved_step``: the step of the checkpoint the run's folder keeps (set by
    :func:`ham.learn.train.train` and ``resume``; None where nothing was kept)."""

    saved_step: int | None = None


def with_article(word: str) -> str:
    """``word`` after "a" or "an" ("a str", "an int", "an ApGymConfig"), for messages."""
    return ("an " if word[:1] in "aeiouAEIOU" else "a ") + word


def _accepted(kind) -> str | None:
    """What a field or argument annotated ``kind`` accepts, in words, or None when this check
    leaves it to its config or function (a generic container, a grid size it parses itself)."""
    if kind is bool:
        return "true or false"
    if kind is int:
        return "an integer"
    if kind is float:
        return "a finite number"
    if kind in (str, dict) or dataclasses.is_dataclass(kind):
        return with_article(kind.__name__)
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin is typing.Literal:
        return ", ".join(map(str, args))
    if origin is tuple and args and Ellipsis not in args and all(a is float for a in args):
        return f"a list of {len(args)} finite numbers"
    if origin is Iterable and args in ((int,), (str,)):
        return "a list of integers" if args == (int,) else "a list of strings"
    if origin in (typing.Union, types.UnionType):
        members = [a for a in args if a is not type(None)]
        words = []
        if str in members and os.PathLike in members:  # said as one
            members = [a for a in members if a not in (str, os.PathLike)]
            words.append("a path (a str or an os.PathLike)")
        words += [_accepted(a) for a in members]
        if None in words:  # a member this check leaves to the config or the function
            return None
        return " or ".join(words + ["None"] * (type(None) in args))
    return None


#: Integers torch and NumPy take: a larger one (``glances = 10**30``) overflowed deep inside
#: (``zeros(): ... Overflow when unpacking long long``).
_INT64 = 2**63


def check_integer(name: str, value: object, low: int = 0) -> int:
    """``value`` as an int ``low .. 2**63-1`` (a count or seed torch and NumPy take), or a
    :class:`HamError` naming it: ``name = VALUE; accepted: an integer LOW .. 2**63-1``."""
    if not (
        isinstance(value, numbers.Integral)
        and not isinstance(value, bool)
        and low <= value < _INT64
    ):
        raise HamError(f"{name} = {brief(value)}; accepted: an integer {low} .. 2**63-1")
    return int(value)


#: Numbers torch's float32 tensors hold: ``lr = 1e300`` was finite here and an overflow in the
#: optimizer (``value cannot be converted to type float without overflow``).
_FLOAT32_MAX = 3.4028234663852886e38


def _fits(kind, v) -> bool:
    if kind is bool:
        return isinstance(v, bool)
    if kind is int:
        return isinstance(v, numbers.Integral) and not isinstance(v, bool) and -_INT64 <= v < _INT64
    if kind is float:
        # abs() first: an int beyond a double's range (10**400) makes isfinite raise
        return (
            isinstance(v, numbers.Real)
            and not isinstance(v, bool)
            and abs(v) <= _FLOAT32_MAX
            and math.isfinite(v)
        )
    if kind in (str, dict) or dataclasses.is_dataclass(kind):
        return isinstance(v, kind)
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin is typing.Literal:
        return isinstance(v, str) and v in args
    if origin is tuple:
        return (
            isinstance(v, (tuple, list)) and len(v) == len(args) and all(_fits(float, x) for x in v)
        )
    if origin is Iterable:  # a list, tuple or range (not a str, not a generator)
        return isinstance(v, (list, tuple, range)) and all(_fits(args[0], x) for x in v)
    # a union (of kinds _accepted reads)
    return any(
        v is None if a is type(None) else isinstance(v, a) if a is os.PathLike else _fits(a, v)
        for a in args
    )


def check_types(config) -> None:
    """Every field of the dataclass ``config`` holds a value of its annotated type: booleans for
    ``bool``, integers (not booleans) for ``int``, finite numbers for ``float``, strings for
    ``str``, one of a ``Literal``'s values, None where the annotation allows it. Run first in
    a config's ``__post_init__``, so its range checks compare numbers (a saved config or a
    Python caller may hand in anything)."""
    hints = typing.get_type_hints(type(config))
    for f in dataclasses.fields(config):
        accepted = _accepted(hints[f.name])
        value = getattr(config, f.name)
        if accepted is not None and not _fits(hints[f.name], value):
            raise HamError(f"{f.name} = {brief(value)}; accepted: {_sized(accepted, value)}")


#: What torch and NumPy say of a size they cannot hold: ``--hidden-units 4611686018427387904``
#: (its LSTM's 4 x hidden rows overflow 64 bits), ``--pitch 1e30`` (a pad of 10**28 m, sampled
#: every 1.25 mm).
_OVERFLOW = (
    "Storage size calculation overflowed",
    "Overflow when unpacking long long",
    "cannot be represented as a SymInt",
    "Maximum allowed dimension exceeded",  # NumPy: an array beyond its index range
    "Maximum allowed size exceeded",
    "array is too big",
)


def too_large(exc: BaseException) -> str | None:
    """One line for a request too large for the machine, not a bug, else None: out of memory
    (NumPy's ``MemoryError``, torch's ``OutOfMemoryError`` and its CPU allocator's
    ``RuntimeError``) or a size beyond what torch or NumPy can index (:data:`_OVERFLOW`)."""
    text = " ".join(str(exc).split()).split(" Exception raised from ")[0]  # torch's C++ frames
    if (
        isinstance(exc, MemoryError)
        or type(exc).__name__ == "OutOfMemoryError"
        or (isinstance(exc, RuntimeError) and "can't allocate memory" in text)
    ):
        what = "out of memory"
    elif isinstance(exc, (RuntimeError, TypeError, ValueError)) and any(
        w in text for w in _OVERFLOW
    ):
        what = "too large to hold"
    else:
        return None
    return (
        f"{what} ({text[:300]}); accepted: a request that fits this machine (fewer envs or "
        "glances, a smaller batch, model, sensor, grid or object set)"
    )


def _sized(accepted: str, value) -> str:
    """``accepted``, saying "of at most 64 bits" when ``value`` is an integer too large for it,
    and "within float32" when it is a number beyond what float32 holds."""
    integer = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if integer and not -_INT64 <= value < _INT64:
        accepted = accepted.replace("an integer", "an integer of at most 64 bits")
    real = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if real and _FLOAT32_MAX < abs(value) != math.inf:  # nan compares False; no float() of 10**400
        accepted = accepted.replace("finite number", "finite number within float32 (|x| <= 3.4e38)")
    return accepted


def check_known_fields(cls, d: dict, what: str) -> None:
    """A dict read from a file names only fields of the dataclass ``cls``: anything else is a
    typo or a file from another version, refused with the accepted names."""
    import dataclasses

    known = [f.name for f in dataclasses.fields(cls)]
    if not isinstance(d, dict):
        raise HamError(f"{what} = {d!r}; accepted: a dict with keys {', '.join(known)}")
    unknown = sorted(str(k) for k in d if k not in known)
    if unknown:
        raise HamError(f"{what} has unknown fields {unknown}; accepted: {', '.join(known)}")


def _not_json(v: object, where: str) -> str | None:
    """``where = VALUE`` of the first part of ``v`` that is no JSON value, else None."""
    if v is None or isinstance(v, (str, bool, int)) or (isinstance(v, float) and math.isfinite(v)):
        return None
    if isinstance(v, (list, tuple)):
        parts = ((f"{where}[{i}]", x) for i, x in enumerate(v))
    elif isinstance(v, dict):
        if not all(isinstance(k, str) for k in v):
            return f"{where} key {next(k for k in v if not isinstance(k, str))!r}"
        parts = ((f"{where}.{k}" if where else k, x) for k, x in v.items())
    else:
        return f"{where} = {brief(v)}"
    return next((bad for w, x in parts if (bad := _not_json(x, w))), None)


def check_json(name: str, value: dict) -> None:
    """``value`` holds only what a run's ``config.json`` keeps as it is: text keys, text,
    booleans, null, integers, finite floats, lists. NaN or inf (which strict JSON lacks and
    which no hyperparameter means), bytes, NumPy scalars and objects are refused, not saved as a
    config that cannot be read back or resumed."""
    bad = _not_json(value, "")
    if bad is not None:
        raise HamError(
            f"{name}: {bad.strip()}; accepted: JSON values (text keys; text, booleans, null, "
            "integers, finite numbers, lists)"
        )


#: The largest run seed: a run's generators are seeded by ``seed * 1000 + stream`` (and the
#: evaluation batches' by multiples of that), and NumPy's and Stable-Baselines3's by ``seed``:
#: 32 bits keep every one of them inside the 64-bit seeds torch and NumPy take.
MAX_SEED = 2**32 - 1


def check_seed(seed) -> None:
    """A run's seed: an integer ``0..MAX_SEED`` (one line naming the value otherwise)."""
    if not (isinstance(seed, int) and not isinstance(seed, bool) and 0 <= seed <= MAX_SEED):
        raise HamError(f"seed = {seed!r}; accepted: an integer 0..{MAX_SEED}")


def checked_arguments(fn):
    """``fn`` with each argument checked against its annotation first, as :func:`check_types`
    checks a config's fields: ``build_table: world = nan; accepted: a WorldConfig`` instead of
    an AttributeError deep inside. Annotations this check does not read (a model, a grid size
    the function parses itself) are left to ``fn``."""
    signature = inspect.signature(fn)
    checks: list[tuple[str, object, str]] | None = None

    def resolve() -> list[tuple[str, object, str]]:
        out = []
        for name, param in signature.parameters.items():
            kind = param.annotation
            if isinstance(kind, str):  # postponed: resolve each alone (some are TYPE_CHECKING-only)
                try:
                    kind = eval(kind, fn.__globals__)  # noqa: S307 - the function's own annotation
                except Exception:  # noqa: BLE001 - a name only a type checker sees: not checked
                    continue
            accepted = None if kind is inspect.Parameter.empty else _accepted(kind)
            if accepted is not None:
                out.append((name, kind, accepted))
        return out

    what = fn.__qualname__.removesuffix(".__init__")  # a class names its constructor

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        nonlocal checks
        if checks is None:
            checks = resolve()
        try:
            bound = signature.bind(*args, **kwargs)
        except TypeError as exc:
            raise HamError(f"{what}: {exc}") from None
        for name, kind, accepted in checks:
            if name in bound.arguments and not _fits(kind, bound.arguments[name]):
                value = bound.arguments[name]
                raise HamError(
                    f"{what}: {name} = {brief(value)}; accepted: {_sized(accepted, value)}"
                )
        return fn(*args, **kwargs)

    return wrapper
