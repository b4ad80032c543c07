"""A user's file kept by its text: the record ``{"name", "sha256", "source"}``.

Objects files (``--objects-file``, :mod:`ham.world.objects`) and plugins (``--plugin``,
:mod:`ham.model.plugin`) are the user's own code. A table or run keeps the file's text, not its
path, so that any process, on any machine, runs the same code when it loads them; the sha256
tells when a record was altered. Running a file's Python turns every failure into one line that
names the file and the line of it that failed.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from ham.errors import HamError

KEYS: tuple[str, ...] = ("name", "sha256", "source")
#: The files whose Python this process ran (:func:`run_python`), name -> what ("plugin", ...):
#: their code runs again later (a plugin core's forward in training), where :func:`raised_in`
#: names them.
_RAN: dict[str, str] = {}


def one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def read_record(path: str | Path, what: str, suffixes: tuple[str, ...], accepted: str) -> dict:
    """The record of the file ``path`` (``what``: "objects file", "plugin"); nothing is run."""
    p, shown = Path(path), str(path)  # as given: Path("") reads "."
    if p.suffix.lower() not in suffixes:
        raise HamError(f"{what} {shown!r}: accepted: {accepted}")
    try:
        source = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise HamError(f"{what} {shown!r} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise HamError(f"cannot read {what} {shown!r}: {one_line(exc)}") from None
    sha = hashlib.sha256(source.encode("utf-8")).hexdigest()
    return {"name": p.name, "sha256": sha, "source": source}


def check_record(record: object, what: str, field: str, suffixes: tuple[str, ...]) -> dict:
    """``record`` if it is complete and its text has its sha256, else an error naming ``field``."""
    if not (
        isinstance(record, dict)
        and set(record) == set(KEYS)
        and all(isinstance(record[k], str) for k in KEYS)
    ):
        got = sorted(record) if isinstance(record, dict) else type(record).__name__
        raise HamError(f"{field} record {got}; accepted: a dict of strings {list(KEYS)}")
    sha = hashlib.sha256(record["source"].encode("utf-8")).hexdigest()
    if sha != record["sha256"]:
        raise HamError(
            f"{what} {record['name']!r}: recorded sha256 {record['sha256'][:16]}... does "
            f"not match its recorded text ({sha[:16]}...); the record was altered"
        )
    if Path(record["name"]).suffix.lower() not in suffixes:
        accepted = ", ".join(f"*{s}" for s in suffixes)
        raise HamError(f"{field} name {record['name']!r}; accepted: {accepted}")
    return record


def run_python(what: str, name: str, source: str, module: str) -> None:
    """Run the Python ``source`` of the file ``name`` as the module ``module``; any failure is one
    line naming the file and the line of it that raised."""
    try:
        code = compile(source, name, "exec")
    except SyntaxError as exc:
        raise HamError(
            f"{what} {name!r} has a syntax error at line {exc.lineno}: {exc.msg}"
        ) from None
    namespace = {"__name__": module, "__file__": name}
    _RAN[name] = what
    call(what, name, exec, code, namespace)


def _innermost(exc: BaseException, names) -> tuple[str, int] | None:
    """The innermost line of the files ``names`` that ``exc`` passed through: (name, line)."""
    tb, found = exc.__traceback__, None
    while tb is not None:
        if tb.tb_frame.f_code.co_filename in names:
            found = (tb.tb_frame.f_code.co_filename, tb.tb_lineno)
        tb = tb.tb_next
    return found


def raised_in(exc: BaseException) -> str | None:
    """One line naming the user's file (one :func:`run_python` ran) and its innermost line that
    ``exc`` passed through, e.g. ``plugin 'late.py' raised ValueError at line 17: late failure``;
    None where ``exc`` passed through none of them (a failure of ours)."""
    found = _innermost(exc, _RAN)
    if found is None:
        return None
    name, line = found
    return f"{_RAN[name]} {name!r} raised {type(exc).__name__} at line {line}: {one_line(exc)}"


def call(what: str, name: str, fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, code of the user's file ``name`` run at last; any failure is one
    line naming the file and the innermost line of it that raised (``what``: "plugin", ...)."""
    try:
        return fn(*args, **kwargs)
    except HamError as exc:
        raise HamError(f"{what} {name!r}: {one_line(exc)}") from None
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - any failure of the user's file
        found = _innermost(exc, (name,))
        where = f" at line {found[1]}" if found else ""
        raise HamError(
            f"{what} {name!r} raised {type(exc).__name__}{where}: {one_line(exc)}"
        ) from None
