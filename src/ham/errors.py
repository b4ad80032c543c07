"""One exception type for every error a user can cause: bad input, a bad file, a bad config.

The CLI prints its message on one line and exits non-zero, without a traceback.
"""

import re


class HamError(ValueError):
    """A user-facing error whose message names the bad value and what is accepted."""


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


#: The largest run seed: a run's generators are seeded by ``seed * 1000 + stream`` (and the
#: evaluation batches' by multiples of that), and NumPy's and Stable-Baselines3's by ``seed``:
#: 32 bits keep every one of them inside the 64-bit seeds torch and NumPy take.
MAX_SEED = 2**32 - 1


def check_seed(seed) -> None:
    """A run's seed: an integer ``0..MAX_SEED`` (one line naming the value otherwise)."""
    if not (isinstance(seed, int) and not isinstance(seed, bool) and 0 <= seed <= MAX_SEED):
        raise HamError(f"seed = {seed!r}; accepted: an integer 0..{MAX_SEED}")
