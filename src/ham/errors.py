"""One exception type for every error a user can cause: bad input, a bad file, a bad config.

The CLI prints its message on one line and exits non-zero, without a traceback.
"""


class HamError(ValueError):
    """A user-facing error whose message names the bad value and what is accepted."""


def check_choices(config) -> None:
    """Every field of the dataclass ``config`` declared with ``metadata={"choices": ...}`` holds
    one of them: the one list of accepted values, which the CLI offers too."""
    import dataclasses

    for f in dataclasses.fields(config):
        allowed = f.metadata.get("choices")
        if allowed is not None and getattr(config, f.name) not in allowed:
            value = getattr(config, f.name)
            raise HamError(f"{f.name} = {value!r}; accepted: {', '.join(allowed)}")
