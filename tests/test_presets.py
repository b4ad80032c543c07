"""World presets (``--world paper-gazebo``), the glance-table cache, and grids whose cells have
worlds of their own (the factor table, docs/grids/factors.toml): real tables, real CLI."""

import json
import os
from dataclasses import replace
from pathlib import Path

import pytest

from ham.errors import HamError
from ham.experiments.grid import Grid, load_grid
from ham.world.cache import cached_table, cached_table_path, table_key
from ham.world.config import WORLD_PRESETS, WorldConfig, world_from_table, world_preset
from ham.world.glance import PoseConfig
from ham.world.table import table_info

DOCS = Path(__file__).resolve().parents[1] / "docs"


def mujoco_available() -> bool:
    try:
        import mujoco  # noqa: F401
    except ImportError:
        return False
    return True


needs_mujoco = pytest.mark.skipif(not mujoco_available(), reason="MuJoCo is not installed")


# --------------------------------------------------------------------------- the preset
def test_the_paper_gazebo_preset_is_the_gazebo_read_out_the_authors_pose_and_sampled_poses():
    p = world_preset("paper-gazebo")
    world = world_from_table(p["world"])
    assert world.simulator == "mujoco" and world.mujoco == {"readout": "gazebo"}
    assert world.pose == PoseConfig.preset("authors") and world.pose.authors_zones
    assert p["grid"] == 201 and p["eval_policy"] == "sample"
    # a copy: changing it does not change the definition
    p["world"]["simulator"] = "fast"
    assert WORLD_PRESETS["paper-gazebo"]["world"]["simulator"] == "mujoco"


def test_fields_laid_over_a_preset_replace_its_fields_and_bad_names_are_refused():
    world = world_from_table({"preset": "paper-gazebo", "simulator": "fast", "mujoco": {}})
    assert world.simulator == "fast" and world.mujoco == {} and world.pose.authors_zones
    assert world_from_table({"preset": "paper-gazebo", "pose": "paper"}).pose == PoseConfig()
    with pytest.raises(HamError, match=r"world preset 'gazebo'; accepted: paper-gazebo"):
        world_from_table({"preset": "gazebo"})
    with pytest.raises(HamError, match=r"pose preset 'author'; accepted: paper, authors"):
        world_from_table({"pose": "author"})


def test_the_cli_refuses_an_unknown_preset_by_name(ham_cli, ham_main, tmp_path):
    r = ham_cli("table", "build", "--world", "paper-gazbo", "--out", str(tmp_path / "t.h5"))
    assert r.returncode == 2
    assert r.stderr.strip() == ("ham: error: world preset 'paper-gazbo'; accepted: paper-gazebo")
    assert not (tmp_path / "t.h5").exists()
    r = ham_main("reproduce", "table1", "--world", "nope", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "world preset 'nope'; accepted: paper-gazebo" in r.stderr


def test_explicit_world_options_override_the_preset(ham_cli, tmp_path):
    from ham.cli.main import build_parser
    from ham.cli.options import world_from_args

    parser = build_parser()

    def world(*extra):
        return world_from_args(parser.parse_args(["glance", "--object", "box", "--x", "0",
                                                  "--phi", "0", *extra]))  # fmt: skip

    gz = world("--world", "paper-gazebo")
    assert gz == world_from_table({"preset": "paper-gazebo"})
    assert world("--world", "paper-gazebo", "--pose", "paper").pose == PoseConfig()
    mj_taxels = world("--world", "paper-gazebo", "--sensor", "taxels")
    assert mj_taxels.simulator == "mujoco" and mj_taxels.mujoco == {}
    assert world("--world", "paper-gazebo", "--taxels", "8").sensor.taxels == 8
    with pytest.raises(HamError, match=r"--sensor gazebo \(world 'paper-gazebo'\) needs "
                                       r"--simulator mujoco \(got 'fast'\)"):  # fmt: skip
        world("--world", "paper-gazebo", "--simulator", "fast")
    assert world() == WorldConfig()  # no preset: the paper's defaults, as before


# --------------------------------------------------------------------------- the cache
def test_a_cached_table_is_built_once_and_keyed_by_the_world(tmp_path):
    world = WorldConfig()
    path = cached_table(world, 3, tmp_path, progress=False)
    assert path == cached_table_path(world, 3, tmp_path) and path.parent == tmp_path
    assert path.name == f"table_3_{table_key(world, 3)}.h5"
    stamp = path.stat().st_mtime_ns
    os.utime(path, ns=(stamp - 10**9, stamp - 10**9))
    assert cached_table(world, 3, tmp_path, progress=False) == path
    assert path.stat().st_mtime_ns == stamp - 10**9  # not rebuilt
    other = replace(world, pose=PoseConfig.preset("authors"))
    assert table_key(other, 3) != table_key(world, 3) and table_key(world, 5) != table_key(world, 3)
    assert WorldConfig.from_dict(table_info(path).world) == world
    assert not list(tmp_path.glob("*.partial")) and not list(tmp_path.glob(".*tmp*"))


def test_the_cache_dir_is_an_option_an_environment_variable_or_home(tmp_path, monkeypatch):
    from ham.world.cache import cache_dir

    monkeypatch.setenv("HAM_CACHE_DIR", str(tmp_path / "env"))
    assert cache_dir() == tmp_path / "env" and cache_dir(tmp_path / "x") == tmp_path / "x"
    monkeypatch.delenv("HAM_CACHE_DIR")
    assert cache_dir() == Path.home() / ".cache" / "ham"
    (tmp_path / "f").write_text("")
    with pytest.raises(HamError, match=r"cache dir '.*f' is a file; accepted: a folder"):
        cache_dir(tmp_path / "f")


@needs_mujoco
def test_table_build_with_the_preset_builds_into_the_cache_once(ham_cli, ham_main, tmp_path):
    cache = tmp_path / "cache"
    args = ["table", "build", "--world", "paper-gazebo", "--grid", "3", "--quiet",
            "--cache-dir", str(cache)]  # fmt: skip
    r = ham_cli(*args, "--out", str(tmp_path / "a.h5"))
    assert r.returncode == 0, r.stderr
    (cached,) = cache.glob("table_3_*.h5")
    info = table_info(tmp_path / "a.h5")
    assert WorldConfig.from_dict(info.world) == world_from_table({"preset": "paper-gazebo"})
    assert info.simulator["name"] == "mujoco" if "name" in info.simulator else True
    stamp = cached.stat().st_mtime_ns
    r = ham_main(*args, "--out", str(tmp_path / "b.h5"))
    assert r.returncode == 0 and f"from the cache: {cached}" in r.stdout
    assert cached.stat().st_mtime_ns == stamp
    assert (tmp_path / "a.h5").read_bytes() == (tmp_path / "b.h5").read_bytes()


@needs_mujoco
def test_train_with_the_preset_evaluates_sampled_poses_unless_told(ham_cli, ham_main, tmp_path):
    common = ["train", "--world", "paper-gazebo", "--online", "--steps", "1", "--glances", "2",
              "--eval-every", "1", "--eval-batches", "1", "--batch-size", "4", "--no-progress"]  # fmt: skip
    r = ham_cli(*common, "--out", str(tmp_path / "a"))
    assert r.returncode == 0, r.stderr
    config = json.loads((tmp_path / "a" / "config.json").read_text())
    assert config["eval_policy"] == "sample" and config["table"] is None
    assert WorldConfig.from_dict(config["world"]) == world_from_table({"preset": "paper-gazebo"})
    r = ham_main(*common, "--eval-policy", "mean", "--out", str(tmp_path / "b"))
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "b" / "config.json").read_text())["eval_policy"] == "mean"


def test_train_refuses_a_preset_with_a_table(ham_main, tmp_path):
    table = cached_table(WorldConfig(), 3, tmp_path, progress=False)
    r = ham_main("train", "--world", "paper-gazebo", "--table", str(table), "--steps", "1",
                "--out", str(tmp_path / "run"))  # fmt: skip
    assert r.returncode == 2 and "brings its own world; remove the world options" in r.stderr


# --------------------------------------------------------------------------- grids
CELL_WORLDS = """\
name = "w"
seeds = 1
[table]
grid = 3
[world]
preset = "paper-gazebo"
[base]
steps = 2
eval_every = 1
eval_batches = 1
batch_size = 4
[axes]
v = [
  { name = "gz" },
  { name = "fast", world = { simulator = "fast", mujoco = {} } },
  { name = "fast-paper", world = { preset = "paper-gazebo", simulator = "fast", mujoco = {}, pose = "paper" } },
]
"""


def test_a_grid_cell_may_have_its_own_world_and_gets_its_own_table(tmp_path):
    (tmp_path / "g.toml").write_text(CELL_WORLDS)
    grid = load_grid(tmp_path / "g.toml")
    assert grid.base["eval_policy"] == "sample"  # the preset's evaluation is the default
    tables = grid.table_paths(tmp_path)
    assert len(tables) == 3 and len(set(tables.values())) == 3
    jobs = {j.key: j.config for j in grid.jobs(tables)}
    gz = world_from_table({"preset": "paper-gazebo"})
    assert WorldConfig.from_dict(jobs["gz-s0"]["world"]) == gz
    fast = WorldConfig.from_dict(jobs["fast-s0"]["world"])
    assert fast == replace(gz, simulator="fast", mujoco={})
    assert WorldConfig.from_dict(jobs["fast-paper-s0"]["world"]).pose == PoseConfig()
    assert jobs["gz-s0"]["table"] == str(tmp_path / "table_3.h5")
    assert jobs["fast-s0"]["table"] == str(tmp_path / f"table_3_{table_key(fast, 3)}.h5")
    # the grid as written out reads back to the same runs
    again = Grid.from_dict(json.loads(json.dumps(grid.to_dict())))
    assert [j.config for j in again.jobs(again.table_paths(tmp_path))] == list(jobs.values())
    # an explicit evaluation wins over the preset's
    text = CELL_WORLDS.replace("batch_size = 4", 'batch_size = 4\neval_policy = "mean"')
    (tmp_path / "m.toml").write_text(text)
    assert load_grid(tmp_path / "m.toml").base["eval_policy"] == "mean"
    # with the cache, the tables are the cache's
    cached = replace(grid, table_cache=True).table_paths(tmp_path, tmp_path / "c")
    assert set(cached.values()) == {
        str(cached_table_path(WorldConfig.from_dict(json.loads(w)), 3, tmp_path / "c"))
        for w in tables
    }


@pytest.mark.parametrize(
    "world, message",
    [
        (
            "{ simulater = 'fast' }",
            r"axis 'v' 'x' world: unknown key 'simulater'; accepted: objects",
        ),
        ("{ preset = 'paper' }", r"world preset 'paper'; accepted: paper-gazebo"),
        ("{ pose = 'x' }", r"pose preset 'x'; accepted: paper, authors"),
        ("'fast'", r"world = 'fast'; accepted: a WorldConfig table"),
    ],
)
def test_bad_cell_worlds_stop_the_grid_with_one_line(tmp_path, world, message):
    text = f"name = 'g'\n[axes]\nv = [{{ name = 'x', world = {world} }}]\n"
    (tmp_path / "g.toml").write_text(text)
    with pytest.raises(HamError, match=message):
        load_grid(tmp_path / "g.toml")


def test_a_grid_with_cell_worlds_runs_each_on_its_own_table(ham_cli, tmp_path):
    text = """\
name = "w"
seeds = 1
[table]
grid = 3
[base]
steps = 2
eval_every = 1
eval_batches = 1
batch_size = 4
[axes]
v = [{ name = "paper" }, { name = "authors", world = { pose = "authors" } }]
"""
    (tmp_path / "g.toml").write_text(text)
    out = tmp_path / "out"
    r = ham_cli("reproduce", "grid", str(tmp_path / "g.toml"), "--workers", "1", "--quiet",
                "--out", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    tables = sorted(p.name for p in out.glob("table_3*.h5"))
    assert len(tables) == 2 and "table_3.h5" in tables
    for key, pose in (("paper-s0", PoseConfig()), ("authors-s0", PoseConfig.preset("authors"))):
        config = json.loads((out / "runs" / key / "config.json").read_text())
        assert WorldConfig.from_dict(table_info(config["table"]).world).pose == pose
    report = (out / "report.md").read_text()
    assert '| `authors` | world: pose="authors" | 1/1 | 2 |' in report


def test_the_factor_grids_in_docs_load():
    grid = load_grid(DOCS / "grids" / "factors.toml")
    cells = [c.name for c in grid.expand()]
    assert len(cells) == 27 and cells[0] == "preset-g1" and grid.table_cache
    assert len(grid.worlds()) == 3 and grid.seeds == (0, 1, 2)
    # the whole table at 2,000 steps: the same factors and worlds, every row
    long = load_grid(DOCS / "grids" / "factors_2000.toml")
    names = [c.name for c in long.expand()]
    assert len(names) == 32 and set(cells) < set(names) and long.worlds() == grid.worlds()
    assert long.base["steps"] == 2000 and long.seeds == (0, 1, 2)


@needs_mujoco
def test_reproduce_with_the_preset_takes_its_table_from_the_cache(ham_cli, ham_main, tmp_path):
    cache, out = tmp_path / "cache", tmp_path / "out"
    r = ham_cli("reproduce", "table1", "--profile", "smoke", "--glances", "1", "--variants",
                "full", "--world", "paper-gazebo", "--cache-dir", str(cache), "--workers", "1",
                "--quiet", "--out", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    (table,) = cache.glob("table_21_*.h5")
    assert not list(out.glob("*.h5"))
    config = json.loads((out / "runs" / "full-concat2-g1-s0" / "config.json").read_text())
    assert config["table"] == str(table) and config["eval_policy"] == "sample"
    assert WorldConfig.from_dict(config["world"]) == world_from_table({"preset": "paper-gazebo"})
    r = ham_main("reproduce", "table1", "--cache-dir", str(cache), "--out", str(out))
    assert r.returncode == 2 and "--cache-dir" in r.stderr and "without --world" in r.stderr
    r = ham_main("reproduce", "grid", str(DOCS / "grids" / "factors.toml"), "--world",
                "paper-gazebo", "--out", str(out))  # fmt: skip
    assert r.returncode == 2 and "a grid file names its world in its [world] table" in r.stderr


FACTORS = """\
name = "f"
key = "{factor}-g{model.glances}"
seeds = 2
evaluate = [{ policy = "sample", batches = 1 }, { policy = "mean", batches = 1 }]
[table]
grid = 3
[base]
steps = 2
eval_every = 1
eval_batches = 1
batch_size = 4
[axes]
factor = [{ name = "preset" }, { name = "l1", normalization = "l1" }]
model.glances = [1, 2]
"""


def test_the_factor_table_reports_each_factor_against_the_preset(ham_cli, tmp_path):
    from ham.experiments import factor_table as ft

    (tmp_path / "f.toml").write_text(FACTORS)
    out = tmp_path / "out"
    r = ham_cli("reproduce", "grid", str(tmp_path / "f.toml"), "--workers", "1", "--quiet",
                "--out", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    t = ft.write(out, tmp_path / "table")
    results = json.loads((out / "results.json").read_text())
    best = {c["cell"]: c["best_accuracy"] for c in results["cells"]}
    for g in (1, 2):
        e = t["factors"]["l1"][g]
        assert e["best"]["mean"] == best[f"l1-g{g}"]["mean"] and e["best"]["n"] == 2
        assert e["delta"]["mean"] == pytest.approx(
            best[f"l1-g{g}"]["mean"] - best[f"preset-g{g}"]["mean"]
        )
        assert {"final_sample", "final_mean"} <= set(e) and e["paper"][0] in (0.547, 0.831)
    md = (tmp_path / "table.md").read_text()
    assert "| paper, Table 1 (full model) | 0.547 ± 0.002 | 0.831 ± 0.002 |" in md
    assert "G=2: sampled | G=2: mean" in md
    assert json.loads((tmp_path / "table.json").read_text())["glances"] == [1, 2]
    assert (tmp_path / "table.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(HamError, match="cannot read"):
        ft.write(tmp_path / "missing", tmp_path / "x")


def test_a_worker_builds_a_missing_cell_table_from_the_cells_world(tmp_path):
    """On a node without the tables, a run of a cell with its own world builds that world's."""
    from ham.experiments.executors import execute_local

    text = """\
name = "w"
[table]
grid = 3
[base]
steps = 1
eval_every = 1
eval_batches = 1
batch_size = 4
[axes]
v = [{ name = "authors", world = { pose = "authors" } }]
"""
    (tmp_path / "g.toml").write_text(text)
    grid = load_grid(tmp_path / "g.toml")
    jobs = grid.jobs(grid.table_paths(tmp_path))
    assert WorldConfig.from_dict(jobs[0].to_dict()["world"]).pose == PoseConfig.preset("authors")
    results: list[dict] = []
    execute_local(jobs, tmp_path, grid.world, 3, 1, results.append)  # the grid's world: paper
    assert [r["status"] for r in results] == ["done"], results
    table = jobs[0].config["table"]
    assert WorldConfig.from_dict(table_info(table).world).pose == PoseConfig.preset("authors")
