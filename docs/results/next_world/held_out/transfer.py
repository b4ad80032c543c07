"""How well held-out composite instances match their class's training instance, glance by glance.

python docs/results/next_world/held_out/transfer.py RUN_DIR [RUN_DIR ...]

No learning: for each run (trained on composite:train, pose dims x,y,phi,phi_y) the world of the
run's code version glances the 12 training instances and the 12 held-out instances
(composite:test; instance k is class k) at the same poses, and each held-out instance is matched
to the training instance whose normalized pressure images are nearest (summed squared distance
over the first g glances). Two sets of poses:

* random: 400 episodes of 6 uniform random 4-D poses (the world's part alone);
* policy: 100 episodes per held-out instance at the run's own poses (its policy's mean poses
  glancing the held-out instance), beside the run's classifier on the same episodes.

Prints one JSON line per run: nearest-neighbour accuracy after 1, 2, 3, 4, 6 glances, both ways,
and the classifier's.
"""

import argparse
import json

import torch

from ham.learn.train import load_run

CLASSES, GLANCES = 12, (1, 2, 3, 4, 6)


def nearest(train: torch.Tensor, test: torch.Tensor, k: int, g: int) -> float:
    """Fraction of episodes whose first ``g`` glances of held-out instance ``k`` (S, E, D) lie
    nearest to training instance ``k``'s at the same poses (``train``: K, S, E, D)."""
    d = ((train[:, :g] - test[None, :g]) ** 2).sum(-1).sum(1)  # (K, E)
    return (d.argmin(0) == k).float().mean().item()


def measure(run: str, episodes_random: int = 400, episodes_policy: int = 100) -> dict:
    train, test = load_run(run), load_run(run, objects="composite:test")
    gen = torch.Generator().manual_seed(0)
    out = {"run": run, "random": {}, "policy": {}, "classifier": {}}
    with torch.no_grad():
        dims = len(train.agent.config.pose_dims)
        q = torch.rand(max(GLANCES), episodes_random, dims, generator=gen) * 2 - 1
        glanced = {}
        for name, run_ in (("train", train), ("test", test)):
            glanced[name] = torch.stack(
                [
                    torch.stack([run_.env.glance(torch.full((episodes_random,), k), p) for p in q])
                    for k in range(CLASSES)
                ]
            )  # (K, S, E, D)
        for g in GLANCES:
            out["random"][g] = (
                sum(nearest(glanced["train"], glanced["test"][k], k, g) for k in range(CLASSES))
                / CLASSES
            )
        for g in GLANCES:
            out["policy"][g] = out["classifier"][g] = 0.0
        for k in range(CLASSES):
            objects = torch.full((episodes_policy,), k)
            episode = test.agent(test.env, objects, gen, greedy=True)
            poses = episode.locations  # (S, E, dims): the poses its policy chose
            held = torch.stack([test.env.glance(objects, p) for p in poses])
            ref = torch.stack(
                [torch.stack([train.env.glance(torch.full_like(objects, j), p) for p in poses])
                 for j in range(CLASSES)]
            )  # fmt: skip
            for g in GLANCES:
                out["policy"][g] += nearest(ref, held, k, g) / CLASSES
                right = (episode.logits[g - 1].argmax(-1) == k).float().mean().item()
                out["classifier"][g] += right / CLASSES
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+")
    args = ap.parse_args()
    torch.set_num_threads(1)
    for run in args.runs:
        m = measure(run)
        print(json.dumps({k: v if k == "run" else {g: round(x, 3) for g, x in v.items()}
                          for k, v in m.items()}))  # fmt: skip


if __name__ == "__main__":
    main()
