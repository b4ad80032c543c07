"""The package's architecture: layers import only downward, and no module imports itself back.

Layers, lowest first: ``errors`` -> ``world`` -> ``envs`` (the world as Gymnasium/ap_gym
environments) -> ``model`` -> ``learn`` -> ``experiments`` -> ``cli``. A module may import from its own layer or a lower one. Every
``import``/``from ... import`` counts, also those inside functions (lazy imports still couple).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "ham"
LAYERS = ["errors", "world", "envs", "model", "learn", "experiments", "cli"]
TOP_LEVEL = {"__init__", "__main__"}  # the package root and `python -m ham` sit above all layers


def module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def ham_imports(path: Path) -> set[str]:
    """The ``ham`` modules ``path`` imports (``from ham.x import y`` counts ``ham.x.y`` when that
    is a module, else ``ham.x``)."""
    modules = {module_name(p) for p in SRC.rglob("*.py")}
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
        else:
            continue
        for name in names:
            if name.startswith("ham") and name in modules:
                found.add(name)
    # `from ham.x import y` where y is a module names both ham.x and ham.x.y: keep the deepest
    return {m for m in found if not any(o.startswith(m + ".") for o in found)} or found


def layer_of(module: str) -> int | None:
    parts = module.split(".")
    if len(parts) == 1 or parts[1] in TOP_LEVEL:
        return None
    return LAYERS.index(parts[1])


def graph() -> dict[str, set[str]]:
    return {module_name(p): ham_imports(p) for p in sorted(SRC.rglob("*.py"))}


def test_every_module_is_in_a_layer():
    stray = [m for m in graph() if m != "ham" and layer_of(m) is None and m != "ham.__main__"]
    missing = [m for m in stray if m.split(".")[1] not in LAYERS]
    assert not missing, f"modules outside the layers {LAYERS}: {missing}"


def test_imports_point_down_the_layers():
    wrong = []
    for module, imports in graph().items():
        here = layer_of(module)
        if here is None:
            continue
        for target in imports:
            there = layer_of(target)
            if there is not None and there > here:
                wrong.append(f"{module} -> {target}")
    assert not wrong, "imports that point up the layers:\n" + "\n".join(wrong)


def test_no_import_cycles():
    g = graph()
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(g.get(node, ())):
            nxt_key = nxt if nxt in g else None
            if nxt_key is None or nxt == node:
                continue
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt) :] + [nxt])
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for node in g:
        if node not in state:
            visit(node, [node])
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


@pytest.mark.parametrize("layer", LAYERS[1:])
def test_each_layer_is_a_package(layer):
    assert (SRC / layer).is_dir() and (SRC / layer / "__init__.py").is_file()


def test_the_readme_map_names_every_module():
    """The README's layout block (a newcomer's map) names every module of each layer, so the map
    cannot fall behind the package."""
    readme = (SRC.parents[1] / "README.md").read_text()
    block = readme[readme.index("```text\nsrc/ham/") :]
    block = block[: block.index("```", 3)]
    sections: dict[str, str] = {}
    for line in block.splitlines()[1:]:
        head = line[:19].strip()
        if head.endswith("/"):
            layer = head[:-1]
        sections[layer] = sections.get(layer, "") + " " + line[19:]
    missing = [
        f"{layer}/{p.stem}"
        for layer in LAYERS[1:]
        for p in sorted((SRC / layer).glob("*.py"))
        if p.stem != "__init__" and not re.search(rf"(?<![\w.]){p.stem}(?!\w)", sections[layer])
    ]
    assert not missing, f"modules missing from the README's layout: {missing}"


def test_the_project_stands_alone():
    """No code, doc or test cites or loads anything outside the repository (docs/sources.md holds
    the facts we rely on, with their public sources)."""
    root = SRC.parents[1]
    needles = ("REFERENCE" + ".md", ".." + "/shared")
    hits = []
    for folder in ("src", "tests", "docs", "benchmarks"):
        for path in (root / folder).rglob("*"):
            if path.suffix in (".py", ".md", ".toml", ".json", ".sh", ".txt"):
                text = path.read_text(errors="replace")
                hits += [f"{path.relative_to(root)}: {n}" for n in needles if n in text]
    readme = (root / "README.md").read_text()
    hits += [f"README.md: {n}" for n in needles if n in readme]
    assert not hits, hits
    assert (root / "docs" / "sources.md").is_file()


#: The one place a file is written and renamed into place (``ham.world.files``), and the glance
#: table builder, which renames its resumable partial HDF5 file when the build is complete.
ATOMIC_WRITERS = {"ham.world.files", "ham.world.table"}
#: Calls that write a file in place: outside ``ATOMIC_WRITERS`` they may only run inside a
#: ``lambda tmp: ...`` handed to ``atomic_write``, which writes a temporary file and renames it.
IN_PLACE = {"write_text", "write_bytes", "savefig", "save", "replace", "dump"}


def test_files_are_written_atomically():
    """No result, report, figure or checkpoint is written in place: a killed run must never
    leave half a file (``ham.world.files.atomic_write``/``write_json``/``write_text``,
    ``ham.world.drawing.save_figure``)."""
    bad = []
    for path in sorted(SRC.rglob("*.py")):
        if module_name(path) in ATOMIC_WRITERS:
            continue
        tree = ast.parse(path.read_text())
        in_lambda = {id(n) for lam in ast.walk(tree) if isinstance(lam, ast.Lambda)
                     for n in ast.walk(lam.body)}  # fmt: skip
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)):
                continue
            name, owner = node.func.attr, node.func.value
            owner_name = owner.id if isinstance(owner, ast.Name) else ""
            if name not in IN_PLACE or id(node) in in_lambda:
                continue
            if name == "dump" and (owner_name != "json" or _to_stdout(node)):
                continue  # JSON printed for the user, not a file
            if name == "save" and owner_name != "torch":
                continue
            if name == "replace" and owner_name != "os":
                continue
            bad.append(f"{module_name(path)}:{node.lineno} {owner_name or '...'}.{name}")
    assert not bad, f"files written in place (use ham.world.files): {bad}"


def _to_stdout(call: ast.Call) -> bool:
    return len(call.args) > 1 and ast.unparse(call.args[1]) == "sys.stdout"
