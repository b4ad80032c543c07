"""``ham reproduce`` with the smoke profile: the real CLI, real runs, local pool and local Ray."""

import concurrent.futures
import contextlib
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from ham.errors import HamError
from ham.experiments.reproduce import PROFILES, plan, reproduce
from tests.conftest import ham_command, one_line_error, run_ham_inprocess


@pytest.fixture(scope="module")
def smoke_all(tmp_path_factory):
    from tests.conftest import run_ham

    out = tmp_path_factory.mktemp("repro")
    r = run_ham(
        "reproduce", "all", "--profile", "smoke", "--workers", "2", "--quiet", "--out", str(out)
    )
    assert r.returncode == 0, r.stderr
    return out, r


def test_all_writes_tables_figures_and_report(smoke_all):
    out, r = smoke_all
    assert "ran 12 run(s), skipped 0 finished" in r.stdout
    t1 = json.loads((out / "table1.json").read_text())
    assert set(t1) == {"1", "2", "3"}
    assert set(t1["3"]) == {"full", "rloc", "mlp", "avg_mlp"}
    assert t1["3"]["full"]["paper"] == [0.91, 0.001] and t1["3"]["full"]["n"] == 1
    assert 0.0 <= t1["3"]["full"]["mean"] <= 1.0
    t2 = json.loads((out / "table2.json").read_text())
    assert set(t2) == {"mul", "concat1", "add", "concat2"}
    # Table 2's concat2 entry is Table 1's full model at 3 glances: one run, not two
    assert t2["concat2"]["mean"] == t1["3"]["full"]["mean"]
    report = (out / "report.md").read_text()
    assert "0.910 ± 0.001" in report and "Reductions from the paper's protocol: steps 12" in report
    assert "torch" in report and "cores" in report
    # which code made the numbers: the commit of the source that ran (a git checkout here)
    env = json.loads((out / "summary.json").read_text())["environment"]
    assert f"commit {env['commit']}," in report
    head = _git("rev-parse", "--short=12", "HEAD")
    if head is not None:
        assert env["commit"].split("+")[0] == head
    for name in ("curves", "learned_vs_random", "per_glance", "heatmap_g3"):
        assert (out / "figures" / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
    # per-object accuracy from each run's last confusion matrix, one row per run group
    assert "## Accuracy per object" in report
    section = report.split("## Accuracy per object")[1].split("##")[0]
    assert "| run | glances | box | ramp_up | convex | ramp_down |" in section
    assert "| full-concat2 (1 seed(s)) | 3 |" in section
    # each glance's pose spread, from each run's last evaluation
    section = report.split("## Pose spread per glance")[1].split("##")[0]
    assert "| run | glance 1 | glance 2 | glance 3 |" in section
    metrics = json.loads((out / "runs" / "rloc-concat2-g2-s0" / "metrics.json").read_text())
    last = metrics["history"][-1]
    spreads = zip(last["pose_spread"], last["pose_spread_within_object"], strict=True)
    cells = [f"{a:.3f} ({b:.3f})" for a, b in spreads]
    assert f"| rloc-concat2 (1 seed(s)) | {cells[0]} | {cells[1]} | — |" in section


def _git(*args: str) -> str | None:
    """git's answer in this checkout, or None where there is no git or no checkout."""
    try:
        done = subprocess.run(
            ["git", *args], capture_output=True, text=True, cwd=Path(__file__).parent
        )
    except OSError:
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def test_the_commit_is_unknown_without_git(tmp_path):
    """No git on the PATH (an installed wheel's machine): the record says so, no error."""
    import sys

    code = "from ham.world.devices import environment_record as e; print(e()['commit'])"
    env = {**os.environ, "PATH": str(tmp_path)}  # an empty folder: no git
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "unknown (no git checkout, or no git)"


def test_a_copy_inside_another_checkout_names_no_commit(tmp_path):
    """ham installed (copied, untracked) into a venv inside some git checkout is not that
    checkout's code: the record names no commit rather than the checkout's."""
    import shutil
    import sys

    if _git("--version") is None:
        pytest.skip("no git here")
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path)]
    subprocess.run([*git, "init", "-q"], check=True)
    (tmp_path / "README").write_text("another project\n")
    subprocess.run([*git, "add", "README"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "x"], check=True)
    site = tmp_path / ".venv" / "site-packages"
    shutil.copytree(Path(__file__).parents[1] / "src" / "ham", site / "ham",
                    ignore=shutil.ignore_patterns("__pycache__"))  # fmt: skip
    code = "from ham.world.devices import environment_record as e; print(e()['commit'])"
    env = {**os.environ, "PYTHONPATH": str(site)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "unknown (no git checkout, or no git)"


_COMMIT_DURING_A_RUN = """
import json, subprocess, sys
from pathlib import Path
import ham.learn.train as t
from ham.model.agent import HamConfig

repo, table, out = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(repo)]
evaluate_run = t.evaluate_run


def committing(*args, **kwargs):  # someone commits to the checkout while the run goes on
    note = repo / "NOTE"
    note.write_text(note.read_text() + "x" if note.exists() else "x")
    subprocess.run([*git, "add", "NOTE"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "later"], check=True)
    return evaluate_run(*args, **kwargs)


t.evaluate_run = committing
config = t.TrainConfig(model=HamConfig(glances=2), steps=2, batch_size=8, eval_every=1,
                       eval_batches=1, table=table)
t.train(config, out, progress=False)
print(json.loads((Path(out) / "timing.json").read_text())["environment"]["commit"])
"""


def test_a_run_names_the_commit_it_started_with(tmp_path, small_table):
    """A commit made while a run goes on (a long run, a developer at work) is not named for the
    run: its timing.json names the code it started with, not the checkout's HEAD at its end."""
    import shutil
    import sys

    if _git("--version") is None:
        pytest.skip("no git here")
    repo = tmp_path / "repo"
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(repo)]
    shutil.copytree(Path(__file__).parents[1] / "src" / "ham", repo / "src" / "ham",
                    ignore=shutil.ignore_patterns("__pycache__"))  # fmt: skip
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "src"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "the code"], check=True)
    started = _git("-C", str(repo), "rev-parse", "--short=12", "HEAD")
    assert started
    env = {**os.environ, "PYTHONPATH": str(repo / "src")}
    args = [
        sys.executable,
        "-c",
        _COMMIT_DURING_A_RUN,
        str(repo),
        small_table,
        str(tmp_path / "run"),
    ]
    done = subprocess.run(args, capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr
    assert _git("-C", str(repo), "rev-parse", "--short=12", "HEAD") != started  # commits made
    assert done.stdout.strip() == started


def test_figures_of_runs_they_do_not_show_are_not_drawn(tmp_path, ham_cli):
    """The figures show the full model and random locations: with --variants mlp there is
    nothing to draw, so no empty picture is written (matplotlib warned of an empty legend on
    stderr three times) and the report says why."""
    r = ham_cli("reproduce", "figures", "--profile", "smoke", "--glances", "1", "--variants",
                "mlp", "--seeds", "1", "--workers", "1", "--quiet", "--out", str(tmp_path))  # fmt: skip
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert json.loads((tmp_path / "summary.json").read_text())["figures"] == []
    assert not list((tmp_path / "figures").glob("*.png"))
    assert (
        "## Figures\n\nNone: the figures show the full model"
        in (tmp_path / "report.md").read_text()
    )


def test_finished_runs_are_skipped(smoke_all, ham_main):
    out, _ = smoke_all
    r = ham_main("reproduce", "table2", "--profile", "smoke", "--quiet", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "ran 0 run(s), skipped 4 finished" in r.stdout


def test_a_failed_run_is_retried_and_reported(tmp_path):
    jobs = plan("table2", PROFILES["smoke"], 1, str(tmp_path / "table_21.h5"))
    broken = tmp_path / "runs" / jobs[0].key
    broken.mkdir(parents=True)
    (broken / "config.json").write_text(json.dumps(jobs[0].config))
    (broken / "checkpoint.pt").write_bytes(b"not a checkpoint")  # an interrupted run, damaged
    summary = reproduce("table2", "smoke", tmp_path, workers=1, progress=False, retries=1)
    assert [f["key"] for f in summary["failures"]] == [jobs[0].key]
    assert "cannot read checkpoint" in summary["failures"][0]["error"]
    assert summary["ran"] == 3
    assert (
        f"`{jobs[0].key}`: HamError: cannot read checkpoint" in (tmp_path / "report.md").read_text()
    )


def test_ray_executor_matches_the_local_pool(smoke_all, tmp_path, ham_cli):
    pytest.importorskip("ray")
    out, _ = smoke_all
    r = ham_cli(
        "reproduce",
        "table2",
        "--profile",
        "smoke",
        "--executor",
        "ray",
        "--quiet",
        "--out",
        str(tmp_path),
    )
    assert r.returncode == 0, r.stderr
    assert "ran 4 run(s)" in r.stdout
    ours = json.loads((tmp_path / "table2.json").read_text())
    local = json.loads((out / "table2.json").read_text())
    assert ours == local  # same seeds, same numbers, whichever executor ran them


def test_ray_workers_compute_as_the_driver_asks(tmp_path):
    """``MKL_CBWR`` set where ``ham reproduce`` runs reaches a Ray cluster's workers through
    Ray's runtime environment (a remote node inherits nothing from this shell), so the nodes of
    a mixed cluster compute alike (docs/results/README.md, "The same numbers on another
    machine")."""
    pytest.importorskip("ray")
    import sys

    code = (
        "import ray\n"
        "from ham.experiments.executors import _connect_ray\n"
        "_connect_ray(None, 1)\n"
        "task = ray.remote(lambda: ray.get_runtime_context().runtime_env.get('env_vars', {}))\n"
        "print(ray.get(task.remote()))\n"
        "ray.shutdown()\n"
    )
    env = {**os.environ, "MKL_CBWR": "COMPATIBLE"}
    env.pop("RAY_ADDRESS", None)
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "{'MKL_CBWR': 'COMPATIBLE'}"


def test_bad_arguments(tmp_path, ham_main):
    with pytest.raises(HamError, match="seeds = 0; accepted: an integer from 1 to 10000"):
        reproduce("table1", "smoke", tmp_path, seeds=0)
    with pytest.raises(HamError, match="profile 'huge'; accepted: smoke, quick, paper"):
        reproduce("table1", "huge", tmp_path)
    r = ham_main("reproduce", "table3", "--out", str(tmp_path))
    assert r.returncode == 2 and "invalid choice: 'table3'" in r.stderr


def test_a_part_of_the_grid(tmp_path, ham_cli):
    """--glances and --variants cut Table 1 to some rows and columns; the rest show as missing."""
    p = PROFILES["paper"].subset([3, 2, 3], ["rloc", "full"])
    assert (p.glances, p.variants) == ((2, 3), ("full", "rloc"))
    assert (
        p.reductions()
        == "glances [2, 3] (paper [1, 2, 3, 4, 6, 8, 10]); variants ['full', 'rloc'] (paper ['full', 'rloc', 'mlp'])"
    )
    assert len(plan("table1", p, 10, "t.h5")) == 2 * 2 * 10
    assert len(plan("all", p, 1, "t.h5")) == 2 * 2 + 3  # Table 2's other combiners stay
    with pytest.raises(
        HamError, match=r"glances = \[0\]; accepted: one or more integers in 1..100"
    ):
        PROFILES["quick"].subset([0])
    with pytest.raises(
        HamError, match=r"variants = \['cnn'\]; accepted: one or more of full, rloc, mlp"
    ):
        PROFILES["quick"].subset(variants=["cnn"])
    r = ham_cli(
        "reproduce", "table1", "--profile", "smoke", "--glances", "2", "--variants", "full",
        "--steps", "7", "--workers", "1", "--quiet", "--out", str(tmp_path),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "ran 1 run(s), skipped 0 finished" in r.stdout
    t1 = json.loads((tmp_path / "table1.json").read_text())
    assert set(t1) == {"2"}
    assert t1["2"]["full"]["n"] == 1 and t1["2"]["rloc"]["n"] == 0
    table = (tmp_path / "table1.md").read_text()
    assert "| 2 | " in table and "—" in table
    assert "variants ['full'] (paper" in (tmp_path / "report.md").read_text()
    assert "steps 7 (paper 50000)" in (tmp_path / "report.md").read_text()
    (run,) = [p for p in tmp_path.rglob("metrics.json") if "full" in str(p)]
    assert json.loads(run.read_text())["history"][-1]["step"] == 7


def test_paper_profile_is_the_papers_protocol():
    p = PROFILES["paper"]
    assert (p.steps, p.seeds, p.eval_every, p.eval_batches, p.heatmap_batches) == (
        50_000,
        10,
        200,
        100,
        1000,
    )
    assert p.reductions() == "none: the paper's protocol"
    jobs = plan("all", p, p.seeds, "t.h5")
    # 3 trained variants x 7 glance counts + 3 more combiners, each over 10 seeds
    assert len(jobs) == (3 * 7 + 3) * 10


def test_the_plans_are_the_papers_runs():
    """Table 1 and Table 2 come from grids (docs/grids.md); each run is exactly the paper's config."""
    from ham.experiments.reproduce import TRAINED_VARIANTS
    from ham.learn.train import TrainConfig
    from ham.model.agent import HamConfig

    p = PROFILES["quick"]
    jobs = plan("all", p, 2, "t.h5", device="cuda")
    wanted = [(v, "concat2", g) for v in TRAINED_VARIANTS for g in p.glances]
    wanted += [("full", c, 3) for c in ("mul", "concat1", "add")]
    assert [(j.variant, j.combiner, j.glances, j.seed) for j in jobs] == [
        (*w, s) for w in wanted for s in (0, 1)
    ]
    for j in jobs:
        model = HamConfig(glances=j.glances, combiner=j.combiner, **TRAINED_VARIANTS[j.variant])
        config = TrainConfig(model=model, steps=p.steps, eval_every=p.eval_every,
                             eval_batches=p.eval_batches, seed=j.seed, table="t.h5", device="cuda")  # fmt: skip
        assert j.config == config.to_dict(), j.key
        assert j.key == f"{j.variant}-{j.combiner}-g{j.glances}-s{j.seed}"


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _pool_workers(pid: int) -> list[int]:
    """The process pool's workers of ``ham reproduce`` ``pid`` (not its resource tracker)."""
    cmdlines = {p: Path(f"/proc/{p}/cmdline").read_bytes() for p in _children(pid)}
    return [p for p, c in cmdlines.items() if b"spawn_main" in c and b"resource_tracker" not in c]


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_a_killed_worker_fails_its_runs_and_the_retry_finishes_them(tmp_path):
    """A pool worker killed mid-run (as the kernel kills one out of memory): its runs are
    recorded as failed with the reason instead of the grid dying with a traceback, and the
    retry trains them to the end."""
    out = tmp_path / "g"
    argv, env = ham_command(
        "reproduce", "table1", "--profile", "smoke", "--glances", "2", "--variants", "full",
        "--seeds", "2", "--steps", "150", "--workers", "2", "--quiet", "--json", "--out", str(out),
    )  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)  # fmt: skip
    deadline = time.monotonic() + 120
    while not list(out.glob("runs/*/config.json")) and time.monotonic() < deadline:
        time.sleep(0.1)
    workers = _pool_workers(proc.pid)
    assert workers, "no pool worker found"
    os.kill(workers[0], signal.SIGKILL)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    assert "retrying" in stderr and "Traceback" not in stderr
    assert json.loads(stdout)["failures"] == []
    for key in ("full-concat2-g2-s0", "full-concat2-g2-s1"):
        m = json.loads((out / "runs" / key / "metrics.json").read_text())
        assert m["steps"] == 150


def _running(pid: int) -> bool:
    """``pid`` exists and has not ended (a zombie waits for a parent that may never reap it)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
@pytest.mark.parametrize("how", ["kill", "ctrl-c"])
def test_a_stopped_reproduce_takes_its_workers_with_it(tmp_path, how):
    """``kill`` of ``ham reproduce`` (SIGTERM to it alone, as a scheduler or a user sends it) or
    Ctrl-C (SIGINT to its whole process group) ends its pool's workers too, at once: left
    training, they would write the runs' checkpoints beside a second ``ham reproduce`` of the
    same folder, and after Ctrl-C each worker went on to the next run. Ctrl-C answers with one
    line and exit 130, and no run starts after it."""
    out = tmp_path / "g"
    argv, env = ham_command(
        "reproduce", "table1", "--profile", "smoke", "--glances", "2", "--variants", "full",
        "--seeds", "3", "--steps", "100000", "--workers", "2", "--quiet", "--out", str(out),
    )  # fmt: skip
    # a terminal's Ctrl-C reaches the whole foreground group; the group's own here, with SIGINT
    # handled (a pytest-xdist worker ignores it, and an ignored SIGINT is inherited)
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                            text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while len(list(out.glob("runs/*/config.json"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        workers = _pool_workers(proc.pid)
        assert len(workers) == 2, workers
        if how == "kill":
            proc.terminate()
        else:
            os.killpg(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=30)
        deadline = time.monotonic() + 30
        while any(_running(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        alive = [w for w in workers if _running(w)]
    finally:
        proc.kill()
        proc.wait()
        for w in workers:  # a failed check leaves none behind
            with contextlib.suppress(ProcessLookupError):
                os.kill(w, signal.SIGKILL)
    assert not alive, f"workers {alive} outlived their ham reproduce"
    if how == "ctrl-c":
        assert proc.returncode == 130
        assert stderr == "ham: interrupted\n"  # no traceback, no warning of leaked semaphores
        assert len(list(out.glob("runs/*"))) == 2  # the third run never started


def _grpc_server(answers: dict[str, str]):
    """A real gRPC server (grpcio, which Ray's GCS and Ray Client server use) whose methods
    ``answers`` answer: ``"OK"`` (an empty reply) or a status name. What a Ray head answers to
    the methods the check calls was read off a real one (Ray 2.60, ``ray start --head``):
    UNAUTHENTICATED from both its GCS and its Ray Client server, asking for the token."""
    import grpc

    def handler(method):
        def answer(request, context):
            if answers[method] != "OK":
                context.abort(getattr(grpc.StatusCode, answers[method]), "no")
            return b""

        return grpc.unary_unary_rpc_method_handler(answer)

    class Handler(grpc.GenericRpcHandler):
        def service(self, details):
            return handler(details.method) if details.method in answers else None

    server = grpc.server(concurrent.futures.ThreadPoolExecutor(max_workers=1))
    server.add_generic_rpc_handlers((Handler(),))
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    return server, port


GCS = "/ray.rpc.NodeInfoGcsService/GetClusterId"
CLIENT = "/ray.rpc.RayletDriver/ClusterInfo"


def test_ray_address_must_be_a_ray_head(monkeypatch):
    """A ``--ray-address`` where a server answers that is not a Ray head is refused at once;
    Ray would wait there for a GCS for minutes (a web server: logging each try; another gRPC
    server: without end). A head that asks for a token without RAY_AUTH_MODE=token here is
    refused at once too (Ray logged InvalidAuthToken for 20-30 s, then failed without why)."""
    import http.server
    import threading

    from ham.experiments.executors import check_ray_address

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    web = http.server.HTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    threading.Thread(target=web.serve_forever, daemon=True).start()
    other, other_port = _grpc_server({})  # a gRPC server of another service
    head, head_port = _grpc_server({GCS: "UNAUTHENTICATED", CLIENT: "UNAUTHENTICATED"})
    open_head, open_port = _grpc_server({GCS: "OK", CLIENT: "OK"})  # RAY_AUTH_MODE=disabled
    try:
        address = f"127.0.0.1:{web.server_address[1]}"
        with pytest.raises(HamError, match=rf"'{address}': something answers there, but not a Ray"):
            check_ray_address("ray", address)
        for address, method in ((f"127.0.0.1:{other_port}", GCS),
                                (f"ray://127.0.0.1:{other_port}", CLIENT)):  # fmt: skip
            with pytest.raises(HamError, match=f"a gRPC server answers there, but not a Ray head "
                               f"\\(its {method}: UNIMPLEMENTED\\)"):  # fmt: skip
                check_ray_address("ray", address)
        for address in (f"127.0.0.1:{head_port}", f"ray://127.0.0.1:{head_port}"):
            with pytest.raises(HamError, match="asks for its auth token .* RAY_AUTH_MODE=token"):
                check_ray_address("ray-batched", address)
        check_ray_address("ray", f"127.0.0.1:{open_port}")
        check_ray_address("ray-batched", f"ray://127.0.0.1:{open_port}")
        monkeypatch.setenv("RAY_AUTH_MODE", "token")  # Ray then sends the token itself
        check_ray_address("ray", f"127.0.0.1:{head_port}")
        check_ray_address("ray", f"ray://127.0.0.1:{head_port}")
        # Ray reads RAY_ADDRESS before --ray-address (and instead of starting a Ray here)
        monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{other_port}")
        for given in (None, "auto", f"127.0.0.1:{open_port}"):
            with pytest.raises(HamError, match="RAY_ADDRESS='127.0.0.1:.*' \\(the environment's"):
                check_ray_address("ray", given)
        check_ray_address("ray", f"ray://127.0.0.1:{open_port}")  # a ray:// address wins
    finally:
        web.shutdown()
        for server in (other, head, open_head):
            server.stop(None)


def test_a_ray_cluster_that_cannot_be_joined_leaves_nothing(tmp_path, monkeypatch):
    """Ray is joined before the table, the plan or the folder is made. A cluster that passes the
    address check and then refuses the connection costs 30 s or more with a real Ray (a Ray
    Client server that times out): here ``ray.init`` raises what Ray raises then."""
    ray = pytest.importorskip("ray")

    def refuse(*args, **kwargs):
        raise ConnectionError("ray client connection timeout. The cluster may be down")

    monkeypatch.setattr(ray, "init", refuse)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    for argv in (["reproduce", "table1", "--profile", "smoke", "--glances", "1"],
                 ["reproduce", "grid", str(Path(__file__).parents[1] / "docs/grids/example.toml")]):  # fmt: skip
        r = run_ham_inprocess(*argv, "--executor", "ray", "--out", "o", cwd=tmp_path)
        assert "ray client connection timeout" in one_line_error(r)
        assert list(tmp_path.iterdir()) == []


def test_ray_tasks_on_cuda_take_a_share_of_a_gpu():
    """Runs on CUDA ask Ray for the cluster's GPUs over its CPUs (as many tasks as CPUs, spread
    over the GPUs); a cluster without GPUs is refused in one line. A GPU cluster cannot exist
    here: its resources stand in as Ray's ``cluster_resources()`` reports them."""
    from ham.experiments.executors import _ray_options, gpu_share

    assert gpu_share({"CPU": 16.0, "GPU": 1.0}) == 0.0625  # the H200 machine: 16 groups
    assert gpu_share({"CPU": 64.0, "GPU": 8.0}) == 0.125  # 8 tasks on each of 8 GPUs
    assert gpu_share({"CPU": 2.0, "GPU": 4.0}) == 1.0  # never more than one GPU
    assert gpu_share({"CPU": 116.0, "GPU": 1.0}) == 0.0086  # Ray's 1e-4 resolution, rounded down
    with pytest.raises(HamError, match="runs on cuda, but the Ray cluster has no GPU"):
        gpu_share({"CPU": 8.0})

    class Cluster:
        def cluster_resources(self):
            return {"CPU": 16.0, "GPU": 1.0}

    jobs = plan("table2", PROFILES["smoke"], 1, "t.h5")
    assert _ray_options(Cluster(), jobs) == {"num_cpus": 1, "max_retries": 0}
    cuda = plan("table2", PROFILES["smoke"], 1, "t.h5", device="cuda")
    assert _ray_options(Cluster(), cuda) == {"num_cpus": 1, "max_retries": 0, "num_gpus": 0.0625}


def test_ray_schedules_cuda_runs_on_the_gpus_it_is_told_of(tmp_path):
    """A real Ray told of one GPU (it need not exist): the runs on CUDA are scheduled with their
    share of it, run, and fail here with the device's one-line reason, no hang, no traceback."""
    ray = pytest.importorskip("ray")
    import torch

    from ham.experiments.executors import execute_ray_batched

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA: the runs would train")
    jobs = plan("table1", PROFILES["smoke"].subset([2], ["full"]), 2, str(tmp_path / "t.h5"),
                device="cuda")  # fmt: skip
    results: list[dict] = []
    ray.init(num_cpus=2, num_gpus=1, include_dashboard=False, log_to_driver=False,
             logging_level="ERROR")  # fmt: skip
    try:
        assert ray.cluster_resources()["GPU"] == 1.0
        execute_ray_batched(jobs, tmp_path, {}, 21, None, results.append)
    finally:
        ray.shutdown()
    assert sorted(r["key"] for r in results) == sorted(j.key for j in jobs)
    for r in results:
        assert r["status"] == "failed", r
        assert (
            r["error"]
            == "HamError: device 'cuda' requested but CUDA is not available; use --device cpu"
        )
