"""Output paths checked before any work starts, and files written atomically.

Every command that writes a file checks its path first with :func:`check_output` (the extension
names the format written, so ``--out x.jpg`` for a PNG is refused, as are directories, other
kinds of existing files and unwritable places) and then writes it with :func:`atomic_write`,
:func:`write_json` or :func:`write_text` (a hidden temporary file beside the target, renamed over
it only when complete; removed on any failure, so no ``.tmp`` file is ever left behind). :func:`check_output_dir` does the same for
folders a command fills (run directories, reports).
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from ham.errors import HamError

#: The first bytes of the formats we write: an existing file is replaced only by one of its kind.
SIGNATURES: dict[str, bytes] = {
    ".png": b"\x89PNG\r\n\x1a\n",
    ".h5": b"\x89HDF\r\n\x1a\n",
    ".hdf5": b"\x89HDF\r\n\x1a\n",
    ".npz": b"PK\x03\x04",  # a zip of arrays
}


def _existing_ancestor(p: Path) -> Path:
    q = p.absolute()
    while not q.exists() and q != q.parent:
        q = q.parent
    return q


def _check_parent(p: Path, what: str, text: str) -> None:
    anc = _existing_ancestor(p.parent)
    if not anc.is_dir():
        raise HamError(
            f"{what} {text!r}: {str(anc)!r} is a file, not a folder; accepted: a path in a folder"
        )
    if not os.access(anc, os.W_OK | os.X_OK):
        raise HamError(f"{what} {text!r}: the folder {str(anc)!r} is not writable")


def check_output(path: str | os.PathLike, suffixes: Sequence[str], *, what: str = "--out") -> Path:
    """``path`` as a :class:`Path` if a file of the format ``suffixes[0]`` may be written there.

    Refused (:class:`HamError` naming the path and what is accepted): an empty path, another
    extension than ``suffixes``, a directory, an existing file that is not of the same kind
    (another format, a device, ...), and a place that cannot be written. Missing parent folders
    are fine (the writer creates them).
    """
    text = os.fspath(path) if isinstance(path, (str, os.PathLike)) else path
    accepted = " or ".join(suffixes)
    if not isinstance(text, str) or not text.strip():
        raise HamError(f"{what} {text!r}; accepted: a file path ending in {accepted}")
    p = Path(text)
    if p.is_dir():
        raise HamError(f"{what} {text!r} is a folder; accepted: a file path ending in {accepted}")
    if p.suffix.lower() not in {s.lower() for s in suffixes}:
        got = f"ends in {p.suffix!r}" if p.suffix else "has no extension"
        raise HamError(
            f"{what} {text!r} {got}; accepted: a path ending in {accepted} (the format written)"
        )
    if p.exists():
        if not p.is_file():
            raise HamError(f"{what} {text!r} exists and is not a regular file")
        sig = SIGNATURES.get(p.suffix.lower())
        if sig is not None and p.stat().st_size > 0:
            with open(p, "rb") as f:
                head = f.read(len(sig))
            if head != sig:
                raise HamError(
                    f"{what} {text!r} exists and is not a {p.suffix} file; accepted: a new path "
                    f"or an existing {p.suffix} file to replace"
                )
        if not os.access(p, os.W_OK):
            raise HamError(f"{what} {text!r} exists and is not writable")
    _check_parent(p, what, text)
    return p


def check_output_dir(path: str | os.PathLike, *, what: str = "--out") -> Path:
    """``path`` as a :class:`Path` if a folder can be created or filled there (not a file)."""
    text = os.fspath(path) if isinstance(path, (str, os.PathLike)) else path
    if not isinstance(text, str) or not text.strip():
        raise HamError(f"{what} {text!r}; accepted: a folder path")
    p = Path(text)
    if p.exists() and not p.is_dir():
        raise HamError(f"{what} {text!r} is a file; accepted: a folder (new or existing)")
    if p.resolve() == Path(p.resolve().anchor):  # a run writes a dozen files and folders there
        raise HamError(f"{what} {text!r} is the filesystem's root; accepted: a folder below it")
    if p.exists():
        if not os.access(p, os.W_OK | os.X_OK):
            raise HamError(f"{what} {text!r}: the folder is not writable")
        return p
    _check_parent(p, what, text)
    return p


@contextlib.contextmanager
def folder_lock(path: str | os.PathLike, *, what: str = "run folder") -> Iterator[None]:
    """Hold the existing folder ``path`` for this process while the block runs.

    A second ``ham`` process that writes the same folder (a run resumed twice at once, a grid
    started again before the first one ended) is refused in one line instead of overwriting the
    other's checkpoints. The lock is an advisory ``flock`` on the folder itself: nothing is
    written, and it goes with the process however that ends (even ``kill -9``).
    """
    import fcntl

    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise HamError(
                f"{what} '{os.fspath(path)}' is in use by another ham process; accepted: a "
                "folder no running ham writes (wait for that one to end, or stop it)"
            ) from None
        yield
    finally:
        os.close(fd)


def atomic_write(
    path: str | os.PathLike, write: Callable[[Path], object], *, what: str = "file"
) -> Path:
    """Call ``write(tmp)`` on a hidden file beside ``path`` and rename it to ``path``.

    The temporary file keeps ``path``'s extension (writers such as matplotlib infer the format
    from it) and is removed whatever happens; an :class:`OSError` becomes a one-line
    :class:`HamError` naming ``path``.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}{path.suffix}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        raise HamError(f"cannot write {what} {str(path)!r}: {exc.strerror or exc}") from None
    finally:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:  # pragma: no cover - the folder itself vanished
            pass
    return path


def write_json(path: str | os.PathLike, obj: object, *, what: str = "file", default=None) -> Path:
    """``obj`` as JSON (one-space indent, a final newline) at ``path``, by :func:`atomic_write`;
    ``default``: as :func:`json.dumps`'s, for values JSON has no type for."""
    return write_text(path, json.dumps(obj, indent=1, default=default) + "\n", what=what)


def write_text(path: str | os.PathLike, text: str, *, what: str = "file") -> Path:
    """``text`` at ``path`` in UTF-8 (reports hold "±" and "—" whatever the locale), by
    :func:`atomic_write`: a report, a Markdown table, a JSON file."""
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"), what=what)
