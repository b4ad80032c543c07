"""One exception type for every error a user can cause: bad input, a bad file, a bad config.

The CLI prints its message on one line and exits non-zero, without a traceback.
"""


class HamError(ValueError):
    """A user-facing error whose message names the bad value and what is accepted."""
