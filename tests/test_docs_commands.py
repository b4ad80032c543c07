"""The `ham` commands the README and the docs show still parse, and the training runs they show
still build their configs: a renamed option, a choice taken away or a combination now refused
shows up here, not in a reader's terminal.

Only what needs no files is checked: each command line is parsed by the real parser; `ham train`
lines without a table, a resume or a world preset (which would build a MuJoCo table) also build
their TrainConfig as the CLI does, without training. Placeholders (``DIR``, ``S``, ``ENV_ID``,
``...``) and prose fragments (a command named without its required arguments) are skipped.
"""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from ham.cli.agent import _config_from_args
from ham.cli.main import build_parser
from tests.conftest import registries_restored

ROOT = Path(__file__).resolve().parents[1]
#: commands the docs name as removed ("... are gone")
GONE = ("envs train",)
#: a word that stands for a value the reader fills in
PLACEHOLDER = re.compile(r"<|\.\.\.|…|\[|\]|\||\$|(^|[:=])[A-Z][A-Z_]*$|^\{")


def _doc_files() -> list[Path]:
    docs = ROOT / "docs"
    return [ROOT / "README.md", *sorted(docs.rglob("*.md")), *sorted(docs.rglob("*.py")),
            *sorted(docs.rglob("*.toml"))]  # fmt: skip


def _commands() -> list[tuple[str, list[str]]]:
    """``(file:line, words after 'ham')`` of every complete `ham ...` line and inline span."""
    found = []
    for path in _doc_files():
        lines = path.read_text().splitlines()
        i = 0
        while i < len(lines):
            line, j = lines[i], i
            while line.rstrip().endswith("\\") and j + 1 < len(lines):  # continued lines
                j += 1
                line = line.rstrip()[:-1] + " " + lines[j].strip()
            where = f"{path.relative_to(ROOT)}:{i + 1}"
            whole = re.match(r"^\s*(?:\$\s*)?(?:[A-Z_]+=\S+\s+)*ham\s(.*)$", line)
            spans = [whole.group(1)] if whole else re.findall(r"`ham ([^`]+)`", line)
            for text in spans:
                text = re.split(r"\s+#|\s\|\s|\s&&\s|\s>\s|\s2>", text)[0].strip()
                try:
                    words = shlex.split(text)
                except ValueError:
                    continue
                if words and not any(PLACEHOLDER.search(w) for w in words):
                    if not any(" ".join(words).startswith(g) for g in GONE):
                        found.append((where, words))
            i = j + 1
    return found


COMMANDS = _commands()


def _parse(words: list[str]):
    """The parsed arguments, or the parser's one-line error."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            return build_parser().parse_args(words)
    except SystemExit as exit:
        return None if not exit.code else err.getvalue().strip()  # --help, --version: fine


def _fragment(error: str) -> bool:
    """A command named in prose without the arguments it requires (``ham train --resume``)."""
    return "arguments are required" in error or "expected one argument" in error


def test_the_docs_show_many_commands():
    assert len(COMMANDS) > 150
    assert {words[0] for _, words in COMMANDS} >= {"train", "table", "reproduce", "sb3", "envs"}


def test_every_command_in_the_docs_parses():
    bad = []
    for where, words in COMMANDS:
        got = _parse(words)
        if isinstance(got, str) and not _fragment(got):
            bad.append(f"{where}: ham {' '.join(words)}: {got}")
    assert not bad, "\n".join(bad)


def _files_exist(words: list[str]) -> bool:
    """The files the command names exist in the checkout (``mine.py`` is the reader's)."""
    for option in ("--plugin", "--objects-file", "--simulator-file"):
        if option in words and not (ROOT / words[words.index(option) + 1]).exists():
            return False
    return True


TRAIN = [
    (where, words)
    for where, words in COMMANDS
    if words[0] == "train" and not {"--table", "--resume", "--world"} & set(words)
    and _files_exist(words)
]  # fmt: skip


def test_some_training_runs_are_shown_without_a_table():
    assert len(TRAIN) > 20


@pytest.mark.parametrize("where, words", TRAIN, ids=[w for w, _ in TRAIN])
def test_every_training_run_in_the_docs_builds_its_config(where, words, monkeypatch):
    monkeypatch.chdir(ROOT)  # the docs' paths (plugins, objects files) are the checkout's
    args = _parse(words)
    if args is None or isinstance(args, str):  # --help; a fragment (the test above)
        return
    with registries_restored():  # a plugin's core, an objects file's objects: not for others
        _config_from_args(args)
