"""Does a policy search? Where its glances go after a first glimpse that missed the object.

    PYTHONPATH=src python docs/results/cs15_search/search.py OUT.json LABEL=RUN_DIR [...]

For ap_gym's ``CircleSquare-s15-nograd-v0`` (one circle or square of 9 px in a 15 x 15 image,
background 0, a 5 x 5 glimpse, the first glance where ap_gym's reset puts it, at random): each run
(a ``ham train`` folder, its final checkpoint) plays 100 balanced batches (6,400 episodes) at
its mean poses (`ham evaluate`'s default seed 12345), and every glimpse is recorded on the way
(the run's env's ``glance``, wrapped). A glimpse that misses the object is all zeros. Per run
and glance ``s >= 2``, split by whether the first glimpse missed:

- ``share``: the episodes in that branch;
- ``hit``: the share whose glimpse ``s`` shows the object (a search finds it after a miss);
- ``found``: the share whose glimpses ``1..s`` showed it at least once;
- ``accuracy``: the classifier's after glance ``s``;
- ``step``: the mean distance between glimpses ``s - 1`` and ``s`` (where they were, ``[-1, 1]``);
- ``away``: the mean position of glimpse ``s`` along the direction from glimpse 1 through the
  image's centre (0: at the centre, or across it; > 0: past the centre, on the far side from
  glimpse 1).

``best-fixed=RUN_DIR`` (a label of its own) plays the run's episodes with the second glance at
each pose of an 11 x 11 lattice instead: the controls' ``hit`` after a miss, the best fixed pose
and the best pose for where the first glimpse was (:func:`fixed_second`).

Writes OUT.json (per run and the mean over runs with the same label) and OUT.png: where the
second glance goes from a first glimpse that missed, one panel a label.
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

from ham.learn.train import load_run

BATCHES, SEED = 100, 12345


def shows_object(glimpses: torch.Tensor) -> torch.Tensor:
    """``(B,)`` whether each glimpse of ``(B, ...)`` shows the object: not all zeros (the
    background is 0 in this task)."""
    return glimpses.flatten(1).abs().sum(1) > 0


def record_glimpses(env) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Wrap ``env.glance``: each glimpse from now on appends where it was ``(B, 2)`` and whether
    it shows the object ``(B,)`` to the list returned."""
    recorded: list[tuple[torch.Tensor, torch.Tensor]] = []
    glance = env.glance

    def recording(objects, q):
        pressure = glance(objects, q)
        # where the glimpse is (the first one's is ap_gym's reset's: its q is not used)
        recorded.append((env.observed_location.clone(), shows_object(pressure)))
        return pressure

    env.glance = recording
    return recorded


def play(run_dir: str) -> dict:
    """The recorded episodes of one run: glimpses' contact ``(S, E)``, poses ``(S, E, 2)``,
    correct answers after each glance ``(S, E)``."""
    run = load_run(run_dir)
    env, agent = run.env, run.agent
    recorded = record_glimpses(env)
    generator = torch.Generator(device=env.device)
    generator.manual_seed(SEED)
    agent.eval()
    hits, poses, correct = [], [], []
    try:
        with torch.no_grad():
            for b in range(BATCHES):
                recorded.clear()
                objects = env.balanced_objects(b)
                episode = agent(env, objects, generator, greedy=True)
                poses.append(torch.stack([q for q, _ in recorded]))
                hits.append(torch.stack([h for _, h in recorded]))
                correct.append(episode.logits.argmax(-1) == objects)
    finally:
        run.close()
    return {
        "hit": torch.cat(hits, 1).numpy(),
        "poses": torch.cat(poses, 1).numpy(),
        "correct": torch.cat(correct, 1).numpy(),
        "steps": run.step,
    }


def fixed_second(run_dir: str, grid: int = 11, bins: int = 5) -> dict:
    """The controls of ``best-fixed=RUN_DIR``: the run's episodes (the same images and first
    glimpses as its :func:`play`) with the second glance at each pose of a ``grid x grid``
    lattice over ``[-1, 1]^2`` in turn, scored by the share of second glimpses that show the
    object after a first glimpse that missed:

    - ``fixed``: the best single pose (a policy that goes to one place whatever it felt);
    - ``by_first``: the best pose for each cell of a ``bins x bins`` partition of where the
      first glimpse was (all a miss tells), chosen on half of the batches and scored on the
      other half, both ways (cross-fitted: the choice never sees the episodes it is scored
      on): the most a search can find at glance 2 on this lattice."""
    run = load_run(run_dir)
    env = run.env
    zero = torch.zeros(env.batch_size, 2)
    lattice = np.linspace(-1.0, 1.0, grid)
    poses = [(float(x), float(y)) for x in lattice for y in lattice]
    hits, miss, where = [], None, None
    try:
        for pose in poses:
            q = torch.tensor([pose], dtype=torch.float32).expand(env.batch_size, 2)
            m, w, h = [], [], []
            for b in range(BATCHES):
                objects = env.balanced_objects(b)
                m.append(~shows_object(env.glance(objects, zero)))
                w.append(env.observed_location.clone())
                h.append(shows_object(env.glance(objects, q)))
            hits.append(torch.cat(h).numpy())
            if miss is None:
                miss, where = torch.cat(m).numpy(), torch.cat(w).numpy()
    finally:
        run.close()
    hits = np.stack(hits)[:, miss]  # (poses, episodes after a miss)
    where = where[miss]
    rate = hits.mean(1)
    cell = np.clip(((where + 1) / 2 * bins).astype(int), 0, bins - 1) @ np.array([bins, 1])
    half = (np.flatnonzero(miss) // env.batch_size) % 2  # each episode's batch: even or odd
    found = np.zeros(hits.shape[1])
    for c in range(bins * bins):
        for fit in (0, 1):
            chosen = (cell == c) & (half == fit)
            scored = (cell == c) & (half != fit)
            if scored.any():
                best = hits[:, chosen].mean(1).argmax() if chosen.any() else rate.argmax()
                found[scored] = hits[best, scored]
    best = int(rate.argmax())
    return {
        "steps": run.step,
        "grid": grid,
        "bins": bins,
        "after_miss": {
            "share": float(miss.mean()),
            "fixed": {"hit": float(rate[best]), "pose": list(poses[best])},
            "by_first": {"hit": float(found.mean())},
        },
    }


def away_from(first: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """The module doc's ``away``: where ``poses`` ``(..., E, 2)`` lie along the direction from
    the first glimpses ``(E, 2)`` through the image's centre (0 at the centre)."""
    direction = -first / np.linalg.norm(first, axis=-1, keepdims=True).clip(1e-9)
    return (poses * direction).sum(-1)


def measures(played: dict) -> dict:
    """The module doc's measures, per glance ``s >= 2`` and branch of the first glimpse."""
    hit, poses, correct = played["hit"], played["poses"], played["correct"]
    glances = hit.shape[0]
    found = np.logical_or.accumulate(hit, axis=0)
    step = np.linalg.norm(np.diff(poses, axis=0), axis=-1)  # (S - 1, E)
    first = poses[0]
    away = away_from(first, poses)  # (S, E)
    out = {
        "steps": played["steps"],
        "episodes": int(hit.shape[1]),
        "glance_1_hit": float(hit[0].mean()),
    }
    for branch, mask in (("after_miss", ~hit[0]), ("after_hit", hit[0])):
        rows = {}
        for s in range(1, glances):
            rows[f"glance_{s + 1}"] = {
                "share": float(mask.mean()),
                "hit": float(hit[s][mask].mean()),
                "found": float(found[s][mask].mean()),
                "accuracy": float(correct[s][mask].mean()),
                "step": float(step[s - 1][mask].mean()),
                "away": float(away[s][mask].mean()),
            }
        out[branch] = rows
    return out


def mean_of(cells: list[dict]) -> dict:
    """Each measure's mean over runs (numbers, and lists of them, elementwise)."""
    first = cells[0]
    if isinstance(first, list):
        return [mean_of(list(c)) for c in zip(*cells, strict=True)]
    if isinstance(first, dict):
        return {k: mean_of([c[k] for c in cells]) for k in first}
    return float(np.mean(cells))


def summary(script: str, argv: list[str], runs: dict[str, list[tuple[str, dict]]]) -> dict:
    """What OUT.json holds: the task, the command that made it, and per label each run's
    measures and their mean over the label's runs."""
    return {
        "env": "ap_gym:CircleSquare-s15-nograd-v0",
        "batches": BATCHES,
        "seed": SEED,
        "command": f"PYTHONPATH=src python docs/results/cs15_search/{script} " + " ".join(argv),
        "labels": {
            label: {"mean": mean_of([m for _, m in cells]), "runs": dict(cells)}
            for label, cells in runs.items()
        },
    }


def main(argv: list[str]) -> None:
    if len(argv) < 2 or not argv[0].endswith(".json") or any("=" not in a for a in argv[1:]):
        sys.exit(__doc__)
    out = Path(argv[0])
    runs: dict[str, list[tuple[str, dict]]] = defaultdict(list)
    moves: dict[str, list[np.ndarray]] = defaultdict(list)
    for spec in argv[1:]:
        label, run_dir = spec.split("=", 1)
        if label == "best-fixed":
            runs[label].append((run_dir, fixed_second(run_dir)))
            print(label, run_dir, json.dumps(runs[label][-1][1]["after_miss"]))
            continue
        played = play(run_dir)
        runs[label].append((run_dir, measures(played)))
        missed = ~played["hit"][0]
        moves[label].append(np.concatenate([played["poses"][0], played["poses"][1]], 1)[missed])
        print(label, run_dir, json.dumps(runs[label][-1][1]["after_miss"]["glance_2"]))
    result = summary("search.py", argv, runs)
    out.write_text(json.dumps(result, indent=1) + "\n")
    if moves:
        plot(moves, out.with_suffix(".png"))


def plot(moves: dict[str, list[np.ndarray]], path: Path, episodes: int = 150) -> None:
    """Glance 1 -> glance 2 after a first glimpse that missed, an arrow an episode, one panel a
    label (the first run of each, its first ``episodes`` misses)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(moves)
    width = max(3.0 * len(labels), 4.2)  # the title's second line fits one panel's figure
    fig, axes = plt.subplots(1, len(labels), figsize=(width, 3.3), squeeze=False)
    for ax, label in zip(axes[0], labels, strict=True):
        m = moves[label][0][:episodes]
        ax.quiver(m[:, 0], m[:, 1], m[:, 2] - m[:, 0], m[:, 3] - m[:, 1], angles="xy",
                  scale_units="xy", scale=1, width=0.004, color="tab:red", alpha=0.5)  # fmt: skip
        ax.scatter(m[:, 0], m[:, 1], s=4, c="0.3")
        ax.set_title(label, fontsize=9)
        ax.set_xlim(-1.1, 1.1)
        ax.set_ylim(-1.1, 1.1)
        ax.set_aspect("equal")
        ax.set_xlabel("x")
    axes[0][0].set_ylabel("y")
    # one or two panels are narrower than the title: two lines
    sep = " " if len(labels) > 2 else "\n"
    fig.suptitle(
        f"CircleSquare-s15-nograd:{sep}glance 1 (dot) missed the object -> glance 2", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main(sys.argv[1:])
