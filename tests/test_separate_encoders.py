"""Separate encoders (``--encoders separate``, HamConfig.encoders; the APPLE study's HAM): the
location policy and the baseline each read a tactile network and a core of their own, which
only their own loss trains; built last; replay, resume, the CLI and bad input."""

from __future__ import annotations

import json

import pytest
import torch

from ham.errors import HamError
from ham.learn.batched import check_batchable
from ham.learn.hybrid_loss import hybrid_loss
from ham.learn.info_loss import info_loss
from ham.learn.train import (
    GlanceRecorder,
    TrainConfig,
    parameter_groups,
    resume,
    train,
)
from ham.model.agent import HamConfig, HapticAttentionModel
from tests.conftest import ok, one_line_error

SEPARATE = HamConfig(glances=3, encoders="separate")


def _episode(env, **kw):
    torch.manual_seed(0)
    model = HapticAttentionModel(HamConfig(glances=3, encoders="separate", **kw))
    episode = model(env, env.sample_objects(), torch.Generator().manual_seed(0))
    return model, episode


def _reached(model, loss) -> set[str]:
    """The parameters that ``loss`` gives a nonzero gradient."""
    params = dict(model.named_parameters())
    grads = torch.autograd.grad(loss, list(params.values()), retain_graph=True, allow_unused=True)
    return {
        n for n, g in zip(params, grads, strict=True) if g is not None and bool(g.abs().sum() > 0)
    }


def _parts(names: set[str]) -> set[str]:
    return {n.split(".")[0] for n in names}


@pytest.mark.parametrize("first_glance", ["random", "learned"])
def test_each_hybrid_loss_trains_its_own_head_and_encoder(env, first_glance):
    model, ep = _episode(env, first_glance=first_glance)
    loss = hybrid_loss(ep, beta=0.4)
    assert _parts(_reached(model, loss.reinforce)) == {"location", "policy_encoder"}
    assert _parts(_reached(model, loss.baseline)) == {"baseline", "value_encoder"}
    assert _parts(_reached(model, loss.classification)) == {"tactile", "core", "classifier"}
    # every weight of both encoders is reached (their tactile networks and cores alike)
    for prefix, part in (("policy_encoder.", loss.reinforce), ("value_encoder.", loss.baseline)):
        names = {n for n, _ in model.named_parameters() if n.startswith(prefix)}
        assert names <= _reached(model, part) | {n for n in names if n.endswith(".bias")}


def test_info_learner_trains_the_encoders_by_policy_and_critic(env):
    model, ep = _episode(env, first_glance="learned")
    loss = info_loss(ep, gamma=0.9, gae_lambda=0.95, entropy_coef=0.01)
    assert _parts(_reached(model, loss.policy)) == {"location", "policy_encoder"}
    assert _parts(_reached(model, loss.critic)) == {"baseline", "value_encoder"}
    assert _parts(_reached(model, loss.classification)) == {"tactile", "core", "classifier"}


def test_shared_encoders_are_the_paper_and_separate_ones_are_built_last():
    torch.manual_seed(3)
    shared = HapticAttentionModel(HamConfig(glances=3))
    torch.manual_seed(3)
    separate = HapticAttentionModel(SEPARATE)
    a, b = shared.state_dict(), separate.state_dict()
    assert not any(k.startswith(("policy_encoder", "value_encoder")) for k in a)
    for k, v in a.items():  # every other part's initial weights as without them
        assert torch.equal(v, b[k]), k
    extra = {k.split(".")[0] for k in b} - {k.split(".")[0] for k in a}
    assert extra == {"policy_encoder", "value_encoder"}
    for name in ("tactile", "core"):  # the same shapes as the classifier's encoder
        mine = getattr(separate.policy_encoder, name).state_dict()
        assert {k: v.shape for k, v in mine.items()} == {
            k: v.shape for k, v in getattr(separate, name).state_dict().items()
        }
    assert "policy_encoder" in separate.describe()


def test_the_classifier_does_not_depend_on_the_separate_encoders(env):
    """The classifier reads its own core: changing the policy's and baseline's encoders changes
    the baselines and the pose distributions, never the logits on the same glances."""
    model, ep = _episode(env)
    pressures = torch.randn(3, 8, model.config.pressure_dim).abs()
    locations = torch.rand(3, 8, 2) * 2 - 1
    first = model.replay(pressures, locations)
    with torch.no_grad():
        for p in [*model.policy_encoder.parameters(), *model.value_encoder.parameters()]:
            p.add_(0.1)
    again = model.replay(pressures, locations)
    assert torch.equal(first.logits, again.logits)
    assert not torch.allclose(first.baselines, again.baselines)
    assert not torch.allclose(first.policy.mu, again.policy.mu)


def test_replay_of_a_recorded_episode_gives_the_played_one(env):
    model, _ = _episode(env, first_glance="learned")
    recorder = GlanceRecorder(env)
    played = model(recorder, env.sample_objects(), torch.Generator().manual_seed(1))
    again = model.replay(
        torch.stack(recorder.pressures), torch.stack(recorder.where), played=played
    )
    assert torch.allclose(again.logits, played.logits)
    assert torch.allclose(again.baselines, played.baselines)
    assert torch.allclose(again.policy.mu, played.policy.mu)
    assert torch.allclose(again.policy.sigma, played.policy.sigma)


def test_the_policy_rate_covers_the_policy_encoder():
    torch.manual_seed(0)
    model = HapticAttentionModel(SEPARATE)
    rest, policy = parameter_groups(model, policy_lr_scale=0.3)
    assert policy["lr_scale"] == 0.3
    names = {id(p): n for n, p in model.named_parameters()}
    assert {names[id(p)].split(".")[0] for p in policy["params"]} == {"location", "policy_encoder"}
    assert {names[id(p)].split(".")[0] for p in rest["params"]} == {
        "tactile",
        "core",
        "classifier",
        "baseline",
        "value_encoder",
    }


def tiny(**kw) -> TrainConfig:
    base = dict(model=SEPARATE, steps=6, batch_size=8, eval_every=2, eval_batches=2, seed=5)
    base.update(kw)
    return TrainConfig(**base)


def test_a_run_with_separate_encoders_learns_its_encoders_and_resumes_bit_identically(tmp_path):
    full = train(tiny(), tmp_path / "full", progress=False)
    train(tiny(steps=4), tmp_path / "half", progress=False)
    half = torch.load(tmp_path / "half" / "checkpoint.pt", weights_only=False)["model"]
    resumed = resume(tmp_path / "half", steps=6, progress=False)
    assert full["history"] == resumed["history"]
    saved = torch.load(tmp_path / "full" / "checkpoint.pt", weights_only=False)["model"]
    assert set(saved) == set(HapticAttentionModel(SEPARATE).state_dict())
    for prefix in ("policy_encoder.", "value_encoder."):  # steps 5 and 6 moved both encoders
        assert any(not torch.equal(v, half[k]) for k, v in saved.items() if k.startswith(prefix))


@pytest.mark.parametrize(
    "make, words",
    [(lambda: HamConfig(encoders="both"), "encoders = 'both'"),
     (lambda: HamConfig(encoders="separate", policy="random"), "policy 'random'"),
     (lambda: HamConfig(encoders="separate", policy="grid"), "policy 'grid'"),
     (lambda: tiny(learner="sac", model=HamConfig(glances=3, encoders="separate",
                                                   policy="learned")), "learner 'sac'")],
)  # fmt: skip
def test_bad_encoder_configs_are_refused_in_one_line(make, words):
    with pytest.raises(HamError, match=words.replace("(", r"\(")) as exc:
        make()
    assert "\n" not in str(exc.value)


def test_separate_encoders_are_not_batched():
    with pytest.raises(HamError, match="encoders 'separate' cannot be batched"):
        check_batchable(tiny())


def test_separate_encoders_through_the_cli(tmp_path, ham_cli):
    out = tmp_path / "run"
    ok(ham_cli("train", "--glances", "3", "--batch-size", "8", "--steps", "2",
               "--encoders", "separate", "--eval-every", "2", "--eval-batches", "2",
               "--no-progress", "--out", str(out)))  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert m["config"]["model"]["encoders"] == "separate"
    ok(ham_cli("evaluate", str(out), "--batches", "2", "--json"))
    line = one_line_error(
        ham_cli(
            "train",
            "--glances",
            "3",
            "--steps",
            "2",
            "--encoders",
            "separate",
            "--policy",
            "random",
            "--out",
            str(tmp_path / "bad"),
        )  # fmt: skip
    )
    assert "encoders 'separate' with policy 'random'" in line
    assert not (tmp_path / "bad").exists()
