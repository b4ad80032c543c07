"""A grid of training runs as data: config overrides x seeds x world, loaded from TOML or JSON.

A grid file names dotted keys into :class:`ham.learn.train.TrainConfig` (``steps``, ``lr``,
``eval_every``, ``model.glances``, ``model.core``, ``model.policy``, ``model.combiner``, ...)::

    name = "policies"
    seeds = 3                      # or a list: [0, 1, 2]
    evaluate = [{policy = "sample", batches = 100}]   # re-evaluate each final checkpoint

    [table]                        # glances from a glance table (the paper's way); no [table]:
    grid = 201                     # the online fast simulator, as `ham train` does

    [world]                        # a WorldConfig dict (default: the paper's world)
    objects = "paper"

    [base]                         # every run
    steps = 3000
    eval_every = 250

    [axes]                         # the cartesian product of these value lists
    model.glances = [2, 3]
    model.policy = ["learned", "random"]

    [[cells]]                      # and runs listed one by one (added to the product)
    name = "g10"
    model.glances = 10
    steps = 1500
    seeds = [0]

An axis whose name is not a config key is a *label* axis: its values are tables, each a ``name``
and the overrides it stands for (Table 1's variants: ``{name = "rloc", model.policy = "random"}``).
A cell's name is ``key`` formatted over the label axes and the resolved config (e.g.
``"{variant}-{model.combiner}-g{model.glances}"``), else ``glances=2_policy=random`` from its
axis values; a run's key is ``<cell>-s<seed>`` and its directory ``runs/<key>``.

Every key is checked against the config dataclasses and every cell's config is built when the
grid is loaded, so a typo or a bad value stops the grid before any run starts.
"""

from __future__ import annotations

import itertools
import json
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ham.errors import HamError
from ham.experiments.runs import MAX_SEEDS

#: Top-level keys of a grid file.
GRID_KEYS = ("name", "description", "seeds", "key", "base", "axes", "cells", "world", "table",
             "evaluate", "plugin")  # fmt: skip
#: TrainConfig fields a grid sets itself rather than through overrides.
RESERVED = {
    "seed": "the grid's seeds",
    "table": "the grid's [table]",
    "world": "the grid's [world]",
    "model.n_objects": "the number of the world's objects",
    "model.plugin": "the grid's plugin = FILE.py",
}
EVAL_SEED = 12345  # the default seed of `ham evaluate`
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._=,+-]*$")


def override_keys() -> list[str]:
    """The dotted keys a grid may set: TrainConfig's fields and ``model.<HamConfig field>``."""
    from ham.learn.train import TrainConfig
    from ham.model.agent import HamConfig

    keys = [f.name for f in fields(TrainConfig) if f.name not in ("model", "world")]
    keys += [f"model.{f.name}" for f in fields(HamConfig)]
    return [k for k in keys if k not in RESERVED]


def flatten(d: Mapping, prefix: str = "", where: str = "grid") -> dict[str, Any]:
    """``{"model": {"glances": 3}}`` -> ``{"model.glances": 3}`` (TOML's dotted keys nest)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping) and not v:  # it would flatten to nothing: set nothing, silently
            raise HamError(
                f"{where}: {key} = {{}}; accepted: a value (an empty table sets nothing)"
            )
        inner = flatten(v, key + ".", where).items() if isinstance(v, Mapping) else [(key, v)]
        for kk, vv in inner:
            if kk in out:  # TOML's "model.glances" and model.glances are two keys, one override
                raise HamError(
                    f"{where}: key {kk!r} is given twice (quoted and dotted); accepted: once"
                )
            out[kk] = vv
    return out


def _check_keys(keys, where: str) -> None:
    accepted = override_keys()
    for k in keys:
        if k in RESERVED:
            raise HamError(f"{where}: key {k!r} is set by {RESERVED[k]}, not by an override")
        if k not in accepted:
            raise HamError(f"{where}: unknown key {k!r}; accepted: {', '.join(accepted)}")


def _seeds(v, where: str) -> tuple[int, ...]:
    def ok(x) -> bool:
        return isinstance(x, int) and not isinstance(x, bool) and x >= 0

    if ok(v) and 1 <= v <= MAX_SEEDS:
        return tuple(range(v))
    if isinstance(v, (list, tuple)) and v and all(ok(x) for x in v) and len(set(v)) == len(v):
        if len(v) <= MAX_SEEDS:
            return tuple(v)
    raise HamError(
        f"{where}: seeds = {v!r}; accepted: a count from 1 to {MAX_SEEDS} or a list of up to "
        f"{MAX_SEEDS} distinct integers >= 0"
    )


def _value_text(v) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    return str(v).lower() if isinstance(v, bool) else str(v)


def _short(key: str) -> str:
    return key.rsplit(".", 1)[-1]


def _fmt_value(v) -> str:
    """A value for a Markdown cell or a run name."""
    return re.sub(r"[^A-Za-z0-9._+-]", "-", _value_text(v))


@dataclass(frozen=True)
class Cell:
    """One point of the grid: its overrides (base included) and the seeds it runs."""

    name: str
    overrides: dict
    seeds: tuple[int, ...]
    #: what distinguishes it from the base: the axis values or the explicit cell's own keys
    settings: dict = field(default_factory=dict)
    #: label-axis values (e.g. ``{"variant": "rloc"}``)
    labels: dict = field(default_factory=dict)


@dataclass(frozen=True)
class GridJob:
    """One training run of a grid."""

    key: str
    cell: str
    seed: int
    labels: dict
    config: dict
    evaluate: list
    #: the cell's own world (a WorldConfig dict) when it has one: a worker builds its table
    world: dict | None = None

    def to_dict(self) -> dict:
        d = {
            "key": self.key,
            "cell": self.cell,
            "seed": self.seed,
            "labels": self.labels,
            "config": self.config,
            "evaluate": self.evaluate,
        }
        if self.world is not None:
            d["world"] = self.world
        return d


@dataclass(frozen=True)
class Grid:
    """A validated grid of runs: ``base`` overrides, ``axes`` (product) and/or ``cells``, x seeds.

    Attributes:
        name: the grid's name (titles of the report).
        base: dotted overrides applied to every run.
        axes: axis -> values; a dotted config key takes scalar values, a label axis tables of
            ``name`` + overrides. Their cartesian product, in file order, are cells.
        cells: more cells, each a table of overrides with an optional ``name`` and ``seeds``.
        seeds: the seeds of every cell without its own.
        key: a format string naming the product's cells (fields: label axes, config values).
        world: the :class:`ham.world.config.WorldConfig` dict every run uses.
        table_grid: ``N`` trains on an N x N glance table built from ``world``; ``None`` online.
        evaluate: re-evaluations of each run's final checkpoint: ``policy``, ``batches``, ``seed``.
        plugin: the record of a plugin file (:mod:`ham.model.plugin`) whose cores, policies and
            learners the cells may name; the runs that use them keep it in their config.
    """

    name: str
    base: dict = field(default_factory=dict)
    axes: dict = field(default_factory=dict)
    cells: list = field(default_factory=list)
    seeds: tuple[int, ...] = (0,)
    key: str | None = None
    world: dict = field(default_factory=dict)
    table_grid: int | None = None
    evaluate: list = field(default_factory=list)
    description: str = ""
    #: take the glance tables from the table cache (:mod:`ham.world.cache`) instead of DIR
    table_cache: bool = False
    plugin: dict | None = None

    # ------------------------------------------------------------------ validation
    def __post_init__(self) -> None:
        from ham.learn.evaluation import check_evaluation
        from ham.world.table import MAX_GRID as MAX_TABLE_GRID

        w = f"grid {self.name!r}"
        if not (isinstance(self.name, str) and _NAME.match(self.name)):
            raise HamError(
                f"grid name {self.name!r}; accepted: letters, digits and . _ = , + - (not empty)"
            )
        if not isinstance(self.description, str):
            raise HamError(f"{w}: description = {self.description!r}; accepted: a string")
        if self.plugin is not None:
            from ham.model.plugin import load_plugin

            try:
                object.__setattr__(self, "_plugin_names", set(load_plugin(self.plugin)))
            except HamError as exc:
                raise HamError(f"{w}: {exc}") from None
        if not isinstance(self.base, Mapping):
            raise HamError(f"{w}: base = {self.base!r}; accepted: a table of overrides")
        object.__setattr__(self, "base", flatten(self.base, where=f"{w} base"))
        _check_keys(self.base, f"{w} base")
        # the world (a WorldConfig table; ``preset`` names a world preset, ``pose`` may name a
        # pose preset): resolved first, a cell's own ``world`` table is laid over it
        preset = self.world.get("preset") if isinstance(self.world, Mapping) else None
        world = _resolve_world(self.world, {}, f"{w} world")
        object.__setattr__(self, "world", world.to_dict())
        object.__setattr__(self, "_n_objects", len(world.resolve_objects()))
        if preset is not None and "eval_policy" not in self.base:
            # the preset's evaluation is the grid's default (an explicit eval_policy wins)
            from ham.world.config import world_preset

            base = {**self.base, "eval_policy": world_preset(preset)["eval_policy"]}
            object.__setattr__(self, "base", base)
        object.__setattr__(self, "seeds", _seeds(self.seeds, w))
        object.__setattr__(self, "axes", self._checked_axes(w))
        object.__setattr__(self, "cells", self._checked_cells(w))
        if not isinstance(self.table_cache, bool):
            raise HamError(f"{w}: table cache = {self.table_cache!r}; accepted: true or false")
        if self.table_grid is not None and not (
            isinstance(self.table_grid, int)
            and not isinstance(self.table_grid, bool)
            and 2 <= self.table_grid <= MAX_TABLE_GRID
        ):
            raise HamError(
                f"{w}: table grid = {self.table_grid!r}; accepted: an integer "
                f"2..{MAX_TABLE_GRID} (the paper uses 201)"
            )
        evals = []
        for i, spec in enumerate(self.evaluate):
            where = f"{w} evaluate[{i}]"
            if not isinstance(spec, Mapping):
                raise HamError(f"{where} = {spec!r}; accepted: a table of policy, batches, seed")
            bad = set(spec) - {"policy", "batches", "seed"}
            if bad:
                raise HamError(
                    f"{where}: unknown key {sorted(bad)[0]!r}; accepted: policy, batches, seed"
                )
            s = {"policy": "mean", "batches": 100, "seed": EVAL_SEED, **spec}
            try:  # as `ham evaluate` takes them
                check_evaluation(s["batches"], s["policy"], s["seed"])
            except HamError as exc:
                raise HamError(f"{where}: {exc}") from None
            if s in evals:
                raise HamError(f"{where}: {s} is listed twice")
            evals.append(s)
        object.__setattr__(self, "evaluate", evals)
        if self.key is not None and not isinstance(self.key, str):
            raise HamError(f"{w}: key = {self.key!r}; accepted: a format string")
        if self.key is not None and not self.axes:
            raise HamError(f"{w}: key {self.key!r} names the axes' cells, but there are no axes")
        # build every cell's config now: a bad value stops the grid before any run starts
        names: dict[str, Cell] = {}
        seen: dict[str, str] = {}
        used = False
        for cell in self.expand():
            if not _NAME.match(cell.name):
                raise HamError(
                    f"{w}: cell name {cell.name!r}; accepted: letters, digits and . _ = , + -"
                )
            if cell.name in names:
                raise HamError(f"{w}: duplicate cell {cell.name!r}")
            try:
                config = self.config(cell.overrides, cell.seeds[0], None)
            except HamError as exc:
                raise HamError(f"{w} cell {cell.name!r}: {exc}") from None
            same = json.dumps({**config.to_dict(), "seed": None}, sort_keys=True)
            if same in seen and set(names[seen[same]].seeds) & set(cell.seeds):
                raise HamError(
                    f"{w}: duplicate cell: {cell.name!r} runs the same config as {seen[same]!r}"
                )
            names[cell.name] = cell
            seen[same] = cell.name
            used = used or config.model.plugin is not None
        if self.plugin is not None and not used:  # nothing reads it: refused, not ignored
            raise HamError(
                f"{w}: plugin {self.plugin['name']!r} registers "
                f"{', '.join(sorted(self._plugin_names))}, which no cell uses; accepted: a grid "
                "whose cells name the plugin's core, policy or learner (model.core, model.policy, "
                "learner)"
            )

    def _checked_axes(self, w: str) -> dict:
        if not isinstance(self.axes, Mapping):
            raise HamError(f"{w}: axes = {self.axes!r}; accepted: a table of value lists")
        axes = {}
        for name, values in _axis_items(self.axes):
            where = f"{w} axis {name!r}"
            if name in axes:
                raise HamError(f"{where} is given twice (quoted and dotted); accepted: once")
            if not isinstance(values, list) or not values:
                raise HamError(f"{where} = {values!r}; accepted: a non-empty list of values")
            if all(isinstance(v, Mapping) for v in values):  # a label axis
                if name in override_keys() or name in RESERVED:
                    raise HamError(f"{where}: a config key takes values, not tables")
                out = []
                for v in values:
                    own_world = v.get("world")
                    v = flatten({k: x for k, x in v.items() if k != "world"}, where=where)
                    if not isinstance(v.get("name"), str) or not v["name"]:
                        raise HamError(f"{where}: value {v!r} has no name")
                    _check_keys([k for k in v if k != "name"], f"{where} {v['name']!r}")
                    if own_world is not None:
                        v["world"] = self._cell_world(own_world, f"{where} {v['name']!r} world")
                    out.append(v)
                names = [v["name"] for v in out]
            else:
                _check_keys([name], w)
                if any(isinstance(v, (Mapping, list)) for v in values):
                    raise HamError(f"{where} = {values!r}; accepted: a list of plain values")
                out, names = list(values), [json.dumps(v) for v in values]
            dup = next((n for n in names if names.count(n) > 1), None)
            if dup is not None:
                raise HamError(f"{where}: value {dup} is listed twice")
            axes[name] = out
        return axes

    def _checked_cells(self, w: str) -> list:
        if not isinstance(self.cells, list):
            raise HamError(f"{w}: cells = {self.cells!r}; accepted: a list of tables")
        out = []
        for i, c in enumerate(self.cells):
            if not isinstance(c, Mapping):
                raise HamError(f"{w} cells[{i}] = {c!r}; accepted: a table of overrides")
            own_world = c.get("world")
            name = c.get("name")
            where = f"{w} cell {name!r}" if isinstance(name, str) and name else f"{w} cells[{i}]"
            c = flatten({k: x for k, x in c.items() if k != "world"}, where=where)
            if "name" in c and not (isinstance(c["name"], str) and c["name"]):
                raise HamError(
                    f"{w} cells[{i}]: name = {c['name']!r}; accepted: letters, digits and "
                    ". _ = , + - (not empty; or no name: named by its values)"
                )
            _check_keys([k for k in c if k not in ("name", "seeds")], where)
            if own_world is not None:
                c["world"] = self._cell_world(own_world, f"{where} world")
            if "seeds" in c:
                c["seeds"] = list(_seeds(c["seeds"], where))
            out.append(c)
        return out

    def _cell_world(self, own, where: str) -> dict:
        """A cell's ``world`` table: ``{"table": its own fields, "world": the resolved dict}``."""
        if isinstance(own, Mapping) and set(own) == {"table", "world"}:
            own = own["table"]  # checked before (dataclasses.replace checks a grid again)
        world = _resolve_world(own, self.world, where)
        return {"table": dict(own), "world": world.to_dict()}

    def worlds(self) -> list[dict]:
        """The distinct worlds of the cells (WorldConfig dicts), the grid's own first."""
        out = [self.world]
        for cell in self.expand():
            w = cell.overrides.get("world", {}).get("world", self.world)
            if w not in out:
                out.append(w)
        return out

    def table_paths(self, root: str | Path, cache_dir: str | Path | None = None) -> dict | None:
        """World (its JSON text) -> glance table path: ``DIR/table_<N>.h5`` for the grid's world,
        ``DIR/table_<N>_<hash>.h5`` for a cell's own world; with ``[table] cache = true`` the
        table cache's path (:mod:`ham.world.cache`). ``None`` when the grid glances online."""
        if self.table_grid is None:
            return None
        from ham.world.cache import cached_table_path, table_key
        from ham.world.config import WorldConfig

        out = {}
        for d in self.worlds():
            world = WorldConfig.from_dict(d)
            if self.table_cache:
                path = cached_table_path(world, self.table_grid, cache_dir)
            elif d == self.world:
                path = Path(root) / f"table_{self.table_grid}.h5"
            else:
                path = (
                    Path(root) / f"table_{self.table_grid}_{table_key(world, self.table_grid)}.h5"
                )
            out[_world_text(d)] = str(path)
        return out

    # ------------------------------------------------------------------ expansion
    def expand(self) -> list[Cell]:
        """The cells: the product of the axes (when there are axes), then the listed cells.

        With neither axes nor cells the grid is one cell, the base.
        """
        cells = []
        if self.axes or not self.cells:
            names = list(self.axes)
            for combo in itertools.product(*(self.axes[n] for n in names)):
                overrides, settings, labels = dict(self.base), {}, {}
                for n, v in zip(names, combo, strict=True):
                    if isinstance(v, Mapping):
                        labels[n] = v["name"]
                        own = {k: x for k, x in v.items() if k != "name"}
                        overrides.update(own)
                        settings.update(own)
                    else:
                        overrides[n] = v
                        settings[n] = v
                name = self._name(overrides, labels, names, combo)
                cells.append(Cell(name, overrides, self.seeds, settings, labels))
        for c in self.cells:
            own = {k: v for k, v in c.items() if k not in ("name", "seeds")}
            name = c.get("name") or _default_name(own)
            seeds = tuple(c["seeds"]) if "seeds" in c else self.seeds
            cells.append(Cell(name, {**self.base, **own}, seeds, own))
        return cells

    def _name(self, overrides: dict, labels: dict, names: list, combo: tuple) -> str:
        if self.key is None:
            parts = []
            for n, v in zip(names, combo, strict=True):
                parts.append(
                    v["name"] if isinstance(v, Mapping) else f"{_short(n)}={_fmt_value(v)}"
                )
            return "_".join(parts) or "base"
        config = self.config(overrides, self.seeds[0], None)
        values = {f.name: getattr(config, f.name) for f in fields(config)}
        try:
            return self.key.format(**{**values, **labels})
        except (KeyError, AttributeError, IndexError, ValueError) as exc:
            fields_ = ", ".join([*labels, *(f"model.{k}" for k in config.model.to_dict()), "..."])
            raise HamError(
                f"grid {self.name!r}: key {self.key!r} cannot be formatted ({exc}); "
                f"accepted fields: {fields_}"
            ) from None

    def config(self, overrides: Mapping, seed: int, table: str | None):
        """The TrainConfig of one run (raises the config's own HamError for a bad value)."""
        from ham.learn.train import TrainConfig
        from ham.model.agent import HamConfig
        from ham.world.config import WorldConfig

        world = self.world
        if "world" in overrides:  # a cell's own world
            world = overrides["world"]["world"]
        n_objects = self._n_objects
        if world != self.world:
            n_objects = len(WorldConfig.from_dict(world).resolve_objects())
        model: dict = {"n_objects": n_objects}
        train: dict = {}
        for k, v in overrides.items():
            if k == "world":
                continue
            if k.startswith("model."):
                model[k[len("model.") :]] = v
            else:
                train[k] = v
        if isinstance(train.get("init_from"), str):  # fine-tuning a grid: each seed its own run
            train["init_from"] = train["init_from"].replace("{seed}", str(seed))
        if self.plugin is not None:  # only the runs that use its core, policy or learner keep it
            uses = {f"core {model.get('core')}", f"policy {model.get('policy')}",
                    f"learner {train.get('learner')}"}  # fmt: skip
            if uses & self._plugin_names:
                model["plugin"] = self.plugin
        return TrainConfig(
            model=HamConfig(**model),
            world=WorldConfig.from_dict(world),
            seed=seed,
            table=table,
            **train,
        )

    def table_path(self, root: str | Path) -> str | None:
        """Where the grid's glance table lives in the output folder (``None``: online)."""
        if self.table_grid is None:
            return None
        return str(Path(root) / f"table_{self.table_grid}.h5")

    def jobs(self, table: str | Mapping | None = None) -> list[GridJob]:
        """Every run: cells in order, seeds within a cell; ``table`` is the glance table's path,
        or :meth:`table_paths`' mapping when cells have worlds of their own."""
        if (table is None) != (self.table_grid is None):
            raise HamError(
                f"grid {self.name!r}: a table path goes with [table] grid (got {table!r})"
            )
        out = []
        for cell in self.expand():
            path = table
            if isinstance(table, Mapping):
                world = cell.overrides.get("world", {}).get("world", self.world)
                path = table[_world_text(world)]
            elif table is not None and "world" in cell.overrides:
                raise HamError(
                    f"grid {self.name!r}: cell {cell.name!r} has its own world; give the "
                    "tables of table_paths()"
                )
            for seed in cell.seeds:
                config = self.config(cell.overrides, seed, path).to_dict()
                key = f"{cell.name}-s{seed}"
                own = cell.overrides.get("world", {}).get("world")
                out.append(GridJob(key, cell.name, seed, dict(cell.labels), config,
                                   list(self.evaluate), own))  # fmt: skip
        return out

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        """The grid as a JSON/TOML-shaped dict that :meth:`from_dict` reads back."""
        d: dict = {"name": self.name}
        if self.description:
            d["description"] = self.description
        d["seeds"] = list(self.seeds)
        if self.key is not None:
            d["key"] = self.key
        d["base"] = dict(self.base)
        if self.axes:
            d["axes"] = {k: [_raw_world(v) for v in vs] for k, vs in self.axes.items()}
        if self.cells:
            d["cells"] = [_raw_world(c) for c in self.cells]
        d["world"] = dict(self.world)
        if self.table_grid is not None:
            d["table"] = {"grid": self.table_grid}
            if self.table_cache:
                d["table"]["cache"] = True
        if self.evaluate:
            d["evaluate"] = list(self.evaluate)
        if self.plugin is not None:
            d["plugin"] = dict(self.plugin)
        return d

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "grid") -> Grid:
        if not isinstance(d, Mapping):
            raise HamError(f"{source}: a grid is a table; got {type(d).__name__}")
        bad = [k for k in d if k not in GRID_KEYS]
        if bad:
            raise HamError(f"{source}: unknown key {bad[0]!r}; accepted: {', '.join(GRID_KEYS)}")
        table, cache = d.get("table"), False
        if table is not None:
            if (
                not isinstance(table, Mapping)
                or set(table) - {"grid", "cache"}
                or "grid" not in table
            ):
                raise HamError(
                    f"{source}: table = {table!r}; accepted: a table with grid = N (and cache = true)"
                )
            table, cache = table["grid"], table.get("cache", False)
        for k in ("evaluate",):
            if not isinstance(d.get(k, []), list):
                raise HamError(f"{source}: {k} = {d[k]!r}; accepted: a list of tables")
        d = _world_files(d, source)
        return cls(
            name=d.get("name", Path(source).stem if source != "grid" else "grid"),
            description=d.get("description", ""),
            base=d.get("base", {}),
            axes=d.get("axes", {}),
            cells=d.get("cells", []),
            seeds=d.get("seeds", 1),
            key=d.get("key"),
            world=d.get("world", {}),
            table_grid=table,
            evaluate=d.get("evaluate", []),
            table_cache=cache,
            plugin=_plugin(d.get("plugin"), source),
        )


def _plugin(value, source: str) -> dict | None:
    """``plugin``: a path to the plugin file (relative to the grid file's folder) or its record."""
    if value is None or isinstance(value, Mapping):
        return None if value is None else dict(value)
    if not isinstance(value, str):
        raise HamError(f"{source}: plugin = {value!r}; accepted: the path of a .py plugin file")
    from ham.model.plugin import read_plugin

    folder = Path(source).parent if source != "grid" else Path()
    try:
        return read_plugin(folder / value)
    except HamError as exc:
        raise HamError(f"{source}: {exc}") from None


#: The world fields that name a file of the user's (relative to the grid file).
_WORLD_FILES: tuple[str, ...] = ("objects_file", "simulator_file")


def _world_files(d: Mapping, source: str) -> dict:
    """``d`` with every world table's ``objects_file`` / ``simulator_file`` path (relative to the
    grid file's folder) replaced by the file's record, as worlds keep them; records pass as they
    are. A world table given an objects file and no ``objects`` takes the file's objects; given a
    simulator file of one simulator and no ``simulator``, that simulator (as the CLI does)."""
    from ham.world.objects import load_objects, read_objects_file
    from ham.world.simulators import load_simulator_file, read_simulator_file

    folder = Path(source).parent if source != "grid" else Path()
    readers = {"objects_file": read_objects_file, "simulator_file": read_simulator_file}

    def world(table, where: str):
        if not isinstance(table, Mapping):
            return table  # refused by name later
        table = dict(table)
        for key in _WORLD_FILES:
            value = table.get(key)
            if value is None or isinstance(value, Mapping):
                continue
            if not isinstance(value, str):
                raise HamError(f"{where}: {key} = {value!r}; accepted: the path of the file")
            try:
                table[key] = readers[key](folder / value)
                if key == "objects_file" and "objects" not in table:
                    table["objects"] = ",".join(load_objects(table[key]))
                if key == "simulator_file" and "simulator" not in table:
                    names = load_simulator_file(table[key])
                    if len(names) == 1:  # else the world names one, or is refused
                        table["simulator"] = names[0]
            except HamError as exc:
                raise HamError(f"{where}: {exc}") from None
        return table

    d = dict(d)
    if "world" in d:
        d["world"] = world(d["world"], f"{source} world")
    if isinstance(d.get("cells"), list):
        d["cells"] = [
            {**c, "world": world(c["world"], f"{source} cell {c.get('name', i)!r} world")}
            if isinstance(c, Mapping) and "world" in c
            else c
            for i, c in enumerate(d["cells"])
        ]
    if isinstance(d.get("axes"), Mapping):
        axes = {}
        for name, values in d["axes"].items():
            if isinstance(values, list):
                values = [
                    {**v, "world": world(v["world"], f"{source} axis {name!r} world")}
                    if isinstance(v, Mapping) and "world" in v
                    else v
                    for v in values
                ]
            axes[name] = values
        d["axes"] = axes
    return d


def _raw_world(v):
    """An axis value or cell with its own world as the file wrote it (its ``world`` table)."""
    if isinstance(v, Mapping) and "world" in v:
        return {**v, "world": v["world"]["table"]}
    return v


def _world_text(world: Mapping) -> str:
    return json.dumps(world, sort_keys=True, default=str)


def _resolve_world(own, under: Mapping, where: str):
    """``own`` (a world table: WorldConfig fields, ``preset``, ``pose`` as a preset name) laid
    over the resolved world dict ``under``; a one-line HamError naming ``where`` if it is bad."""
    from ham.world.config import WorldConfig, world_from_table

    accepted = [f.name for f in fields(WorldConfig)] + ["preset"]
    if not isinstance(own, Mapping):
        raise HamError(f"{where} = {own!r}; accepted: a WorldConfig table")
    for k in own:
        if k not in accepted:
            raise HamError(f"{where}: unknown key {k!r}; accepted: {', '.join(accepted)}")
    try:
        if "preset" in own:  # a preset starts afresh: only the cell's own fields replace it
            return world_from_table(dict(own))
        return world_from_table({**under, **own})
    except HamError as exc:
        raise HamError(f"{where}: {exc}") from None


def _axis_items(axes: Mapping):
    """Axis name -> values; TOML's ``model.glances = [...]`` arrives nested, so flatten it."""
    for k, v in axes.items():
        if isinstance(v, Mapping) and v:  # an empty one is refused as an axis's values
            for kk, vv in _axis_items(v):
                yield f"{k}.{kk}", vv
        else:
            yield k, v


def _default_name(own: Mapping) -> str:
    return "_".join(f"{_short(k)}={_fmt_value(v)}" for k, v in own.items()) or "base"


def load_grid(path: str | Path) -> Grid:
    """Read a grid from a ``.toml`` or ``.json`` file (validated; one-line HamError if not)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise HamError(f"grid file {str(path)!r} cannot be read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise HamError(f"grid file {str(path)!r} is not UTF-8 text ({exc.reason})") from None
    if path.suffix == ".toml":
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise HamError(f"grid file {str(path)!r} is not valid TOML: {exc}") from None
    elif path.suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise HamError(f"grid file {str(path)!r} is not valid JSON: {exc}") from None
    else:
        raise HamError(f"grid file {str(path)!r}; accepted: a .toml or .json file")
    return Grid.from_dict(data, source=str(path))


def settings_text(settings: Mapping) -> str:
    """``glances=3, policy=random`` for a report."""

    def text(k, v) -> str:
        if k == "world":  # a cell's own world: the fields it sets (a file by its name)
            return "world: " + ", ".join(
                f"{a}={json.dumps(b['name'] if a in _WORLD_FILES and isinstance(b, Mapping) else b)}"
                for a, b in v["table"].items()
            )
        return f"{_short(k)}={_value_text(v)}"

    return ", ".join(text(k, v) for k, v in settings.items())
