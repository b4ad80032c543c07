"""The information learner (``--learner info``): its loss's math, what each part trains, the
learned first glance, the env-steps budget, the CLI end to end and bit-identical resume."""

from __future__ import annotations

import json
import math

import pytest
import torch
from torch.nn import functional as F

from ham.errors import HamError
from ham.learn.info_loss import advantages, hit_gain, info_loss, information_gain
from ham.learn.train import TrainConfig, load_run, resume, train
from ham.model.agent import HamConfig, HapticAttentionModel

INFO = ["--learner", "info", "--optimizer", "adam", "--lr", "0.003", "--no-progress"]


def _episode(env, glances=3, **kw):
    torch.manual_seed(0)
    model = HapticAttentionModel(HamConfig(glances=glances, **kw))
    episode = model(env, env.sample_objects(), torch.Generator().manual_seed(0))
    return model, episode


def tiny(**kw) -> TrainConfig:
    base = dict(
        model=HamConfig(glances=3, first_glance="learned"),
        steps=6,
        batch_size=8,
        eval_every=2,
        eval_batches=2,
        seed=5,
        learner="info",
        optimizer="adam",
        lr=3e-3,
    )
    base.update(kw)
    return TrainConfig(**base)


# --------------------------------------------------------------------------- the math
def test_information_gain_telescopes_to_log_k_minus_the_last_cross_entropy():
    g = torch.Generator().manual_seed(0)
    s, b, k = 5, 7, 4
    logits = torch.randn(s, b, k, generator=g, dtype=torch.float64)
    objects = torch.randint(0, k, (b,), generator=g)
    gain = information_gain(logits, objects)
    assert gain.shape == (s, b)
    ce = torch.stack([F.cross_entropy(logits[i], objects, reduction="none") for i in range(s)])
    assert torch.allclose(gain.sum(0), math.log(k) - ce[-1])
    assert torch.allclose(gain[0], math.log(k) - ce[0])
    assert torch.allclose(gain[1:], ce[:-1] - ce[1:])
    # the return of glance s with gamma = 1 is CE_{s-1} - CE_S
    returns = gain.flip(0).cumsum(0).flip(0)
    before = torch.cat([torch.full((1, b), math.log(k), dtype=torch.float64), ce[:-1]])
    assert torch.allclose(returns, before - ce[-1])


def test_hit_gain_is_the_change_of_the_0_1_score_and_telescopes_to_the_paper_s_reward():
    from ham.learn.hybrid_loss import reward

    g = torch.Generator().manual_seed(1)
    s, b, k = 4, 50, 3
    logits = torch.randn(s, b, k, generator=g)
    objects = torch.randint(0, k, (b,), generator=g)
    hits = hit_gain(logits, objects)
    score = torch.stack([reward(logits[i], objects) for i in range(s)])  # c_s, by the paper
    assert torch.equal(hits[0], score[0] - 1 / k)
    assert torch.equal(hits[1:], score[1:] - score[:-1])
    assert set(hits[1:].unique().tolist()) == {-1.0, 0.0, 1.0}  # rises, stays and falls
    # with gamma = 1 the return of glance s is c_S - c_{s-1}
    returns = hits.flip(0).cumsum(0).flip(0)
    before = torch.cat([torch.full((1, b), 1 / k), score[:-1]])
    assert torch.allclose(returns, score[-1] - before)


def test_the_hit_reward_changes_only_the_policy_s_and_critic_s_targets(env):
    _, episode = _episode(env, glances=4)
    gain = info_loss(episode, gamma=1.0)
    hit = info_loss(episode, gamma=1.0, reward_kind="hit")
    assert torch.equal(gain.classification, hit.classification)
    assert torch.equal(hit.gain, hit_gain(episode.logits, episode.objects))
    values = episode.values().detach()
    ret = advantages(hit.gain[1:], values, 1.0, 1.0)[1]
    assert torch.allclose(((ret - episode.values()) ** 2).sum(0).mean(), hit.critic)
    assert not torch.allclose(gain.critic, hit.critic)
    with pytest.raises(HamError, match="info_reward = 'score'; accepted: gain, hit"):
        info_loss(episode, reward_kind="score")


@pytest.mark.parametrize("epochs", [1, 2])
def test_a_run_trains_on_the_hit_reward_and_other_learners_refuse_it(tmp_path, epochs):
    with pytest.raises(HamError, match="info_reward = 'hit' with learner 'hybrid'"):
        TrainConfig(info_reward="hit")
    with pytest.raises(HamError, match="info_reward"):
        tiny(info_reward="score")
    metrics = train(tiny(info_reward="hit", epochs=epochs), tmp_path / "hit", progress=False)
    gained = train(tiny(epochs=epochs), tmp_path / "gain", progress=False)
    # the policy trains on another reward: its mean poses part
    assert [r["mu_mean"] for r in metrics["history"]] != [r["mu_mean"] for r in gained["history"]]
    saved = json.loads((tmp_path / "hit" / "config.json").read_text())
    assert saved["info_reward"] == "hit"


@pytest.mark.parametrize("gamma", [1.0, 0.9, 0.5])
def test_gae_with_lambda_one_is_the_monte_carlo_return_minus_the_value(gamma):
    g = torch.Generator().manual_seed(1)
    rewards = torch.randn(6, 5, generator=g, dtype=torch.float64)
    values = torch.randn(6, 5, generator=g, dtype=torch.float64)
    adv, ret = advantages(rewards, values, gamma, 1.0)
    mc = torch.zeros_like(rewards)
    running = torch.zeros(5, dtype=torch.float64)
    for t in range(5, -1, -1):
        running = rewards[t] + gamma * running
        mc[t] = running
    assert torch.allclose(ret, mc)
    assert torch.allclose(adv, mc - values)


def test_gae_with_lambda_zero_is_the_td_error():
    g = torch.Generator().manual_seed(2)
    rewards = torch.randn(4, 3, generator=g, dtype=torch.float64)
    values = torch.randn(4, 3, generator=g, dtype=torch.float64)
    adv, _ = advantages(rewards, values, 0.8, 0.0)
    next_values = torch.cat([values[1:], torch.zeros(1, 3, dtype=torch.float64)])
    assert torch.allclose(adv, rewards + 0.8 * next_values - values)


@pytest.mark.parametrize("first_glance", ["random", "learned"])
def test_the_parts_train_disjoint_weights(env, first_glance):
    """The policy term reaches only the location network, the critic only the baseline layer,
    the classification neither of them (and the loss's total is their weighted sum)."""
    model, episode = _episode(env, first_glance=first_glance)
    loss = info_loss(episode, gamma=0.9, gae_lambda=0.95, entropy_coef=0.01)
    groups = {
        "location": {n for n, _ in model.named_parameters() if n.startswith("location.")},
        "baseline": {n for n, _ in model.named_parameters() if n.startswith("baseline.")},
    }
    groups["rest"] = {n for n, _ in model.named_parameters()} - set().union(*groups.values())
    expected = {
        "policy": {"location"},
        "entropy": {"location"},
        "critic": {"baseline"},
        "classification": {"rest"},
    }
    for part, owners in expected.items():
        params = dict(model.named_parameters())
        grads = torch.autograd.grad(
            getattr(loss, part), list(params.values()), retain_graph=True, allow_unused=True
        )
        reached = {n for n, gr in zip(params, grads, strict=True)
                   if gr is not None and bool(gr.abs().sum() > 0)}  # fmt: skip
        allowed = set().union(*(groups[o] for o in owners))
        assert reached, part
        assert reached <= allowed, (part, sorted(reached - allowed))
    total = loss.classification + loss.policy + loss.critic - 0.01 * loss.entropy
    assert torch.allclose(loss.total, total)


def test_random_policy_trains_only_the_classifier(env):
    model, episode = _episode(env, policy="random")
    loss = info_loss(episode)
    assert float(loss.policy) == 0.0 and float(loss.critic) == 0.0
    assert torch.equal(loss.total, loss.classification)


@pytest.mark.parametrize("kw", [{"gamma": 1.5}, {"gae_lambda": -0.1}, {"gamma": float("nan")}])
def test_info_loss_refuses_bad_discounts(env, kw):
    _, episode = _episode(env)
    with pytest.raises(HamError):
        info_loss(episode, **kw)


# --------------------------------------------------------------------------- first glance
@pytest.mark.parametrize("first_glance", ["random", "learned"])
def test_learned_first_glance_episode_shapes(env, first_glance):
    _, episode = _episode(env, glances=4, first_glance=first_glance)
    b = episode.objects.shape[0]
    chosen = 4 if first_glance == "learned" else 3
    assert episode.locations.shape == (4, b, 2)
    assert episode.logits.shape == (4, b, 4) and episode.baselines.shape == (4, b)
    assert tuple(episode.policy.batch_shape) == (chosen, b)
    assert episode.values().shape == (chosen, b)
    assert episode.locations[episode.chosen].shape == (chosen, b, 2)
    if first_glance == "learned":
        assert episode.first_baseline.shape == (b,)
        # the first pose comes from the policy at the zero core output: one greedy pose for all
        model, _ = _episode(env, glances=4, first_glance=first_glance)
        greedy = model(env, episode.objects, None, greedy=True)
        assert torch.equal(greedy.locations[0], greedy.locations[0][:1].expand(b, 2))
    else:
        assert episode.first_baseline is None


# --------------------------------------------------------------------------- config
def test_env_steps_define_the_steps():
    c = TrainConfig(env_steps=100_000, batch_size=16, model=HamConfig(glances=10))
    assert c.steps == 625  # ceil(100000 / 160)
    c = TrainConfig(env_steps=1001, batch_size=10, model=HamConfig(glances=10))
    assert c.steps == 11
    assert TrainConfig.from_dict(json.loads(json.dumps(c.to_dict()))) == c
    assert TrainConfig(steps=7).env_steps is None


@pytest.mark.parametrize(
    "kw",
    [{"env_steps": 0}, {"env_steps": 1.5}, {"policy_lr_scale": -0.1}, {"policy_lr_scale": True},
     {"policy_lr_scale": float("inf")}, {"gamma": 2.0}, {"entropy_coef": -1.0},
     {"learner": "ppo"}, {"optimizer": "rmsprop"}],
)  # fmt: skip
def test_bad_info_config(kw):
    with pytest.raises(HamError):
        TrainConfig(**kw)


def test_policy_lr_scale_gives_the_location_network_its_own_rate(tmp_path):
    from ham.learn.train import Run, train_step

    run = Run.create(tiny(policy_lr_scale=0.1, lr_step=1_000_000))
    try:
        train_step(run)
        groups = run.optimizer.param_groups
        assert len(groups) == 2
        assert groups[0]["lr"] == pytest.approx(3e-3) and groups[1]["lr"] == pytest.approx(3e-4)
        location = {id(p) for p in run.agent.location.parameters()}
        assert {id(p) for p in groups[1]["params"]} == location
        assert not location & {id(p) for p in groups[0]["params"]}
    finally:
        run.close()
    run = Run.create(tiny())
    try:
        assert len(run.optimizer.param_groups) == 1
    finally:
        run.close()


@pytest.mark.parametrize("optimizer", ["sgd", "adam"])
def test_a_policy_lr_scale_of_0_keeps_the_policy(optimizer):
    """policy_lr_scale = 0: the location network stays as it was, bit for bit, while the rest
    learns (fine-tuning a run's reader on a new pad, docs/sim_to_real.md)."""
    from ham.learn.train import Run, train_step

    run = Run.create(tiny(policy_lr_scale=0.0, optimizer=optimizer, learner="hybrid"))
    try:
        before = {n: p.detach().clone() for n, p in run.agent.named_parameters()}
        for _ in range(3):
            train_step(run)
        after = dict(run.agent.named_parameters())
        moved = {n for n in before if not torch.equal(before[n], after[n])}
        location = {f"location.{n}" for n, _ in run.agent.location.named_parameters()}
        assert location and not moved & location
        assert moved == set(before) - location  # everything else learned
    finally:
        run.close()


# --------------------------------------------------------------------------- runs
def test_info_learner_through_the_cli(tmp_path, ham_cli, ham_main):
    out = tmp_path / "run"
    p = ham_cli("train", *INFO, "--glances", "3", "--batch-size", "8", "--env-steps", "100",
                "--first-glance", "learned", "--gamma", "0.5", "--entropy-coef", "0.001",
                "--eval-every", "2", "--eval-batches", "2", "--seed", "1", "--out", str(out))  # fmt: skip
    assert p.returncode == 0, p.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["steps"] == 5  # ceil(100 / (8 * 3))
    assert m["env_steps"] == 5 * 8 * 3
    assert m["config"]["env_steps"] == 100 and m["config"]["learner"] == "info"
    assert m["config"]["model"]["first_glance"] == "learned"
    for key in ("average_accuracy", "env_steps_to_0.95", "env_steps_to_0.99",
                "glances_to_0.95", "glances_to_0.99", "final_accuracy", "history"):  # fmt: skip
        assert key in m, key
    assert m["average_accuracy"] == pytest.approx(sum(m["accuracy_per_glance"]) / 3)
    assert [h["step"] for h in m["history"]] == [0, 2, 4, 5]
    assert [h["env_steps"] for h in m["history"]] == [0, 48, 96, 120]
    for h in m["history"]:
        assert h["average_accuracy"] == pytest.approx(sum(h["accuracy_per_glance"]) / 3)
    reached = m["env_steps_to_0.95"]
    hits = [h["env_steps"] for h in m["history"] if h["accuracy"] >= 0.95]
    assert reached == (hits[0] if hits else None)
    # help is derived from the dataclass
    h = ham_main("train", "--help")
    assert "--env-steps" in h.stdout and "--policy-lr-scale" in h.stdout
    # one training length
    p = ham_main("train", *INFO, "--steps", "3", "--env-steps", "100", "--out", str(tmp_path / "x"))
    assert p.returncode == 2 and "--env-steps" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and not (tmp_path / "x").exists()


@pytest.mark.parametrize("policy_lr_scale", [1.0, 0.1])
def test_info_learner_resumes_bit_identically(tmp_path, policy_lr_scale):
    kw = dict(policy_lr_scale=policy_lr_scale, gamma=0.5, gae_lambda=0.9, entropy_coef=0.01)
    full = train(tiny(steps=6, **kw), tmp_path / "full", progress=False)
    train(tiny(steps=4, **kw), tmp_path / "half", progress=False)
    resumed = resume(tmp_path / "half", steps=6, progress=False)
    assert resumed == full  # every float of the history
    a, b = load_run(tmp_path / "full"), load_run(tmp_path / "half")
    for (n, p), (_, q) in zip(
        a.agent.state_dict().items(), b.agent.state_dict().items(), strict=True
    ):
        assert torch.equal(p, q), n


def test_resume_to_an_env_steps_budget(tmp_path):
    full = train(tiny(env_steps=6 * 8 * 3), tmp_path / "full", progress=False)
    assert full["steps"] == 6
    train(tiny(env_steps=4 * 8 * 3), tmp_path / "half", progress=False)
    resumed = resume(tmp_path / "half", env_steps=6 * 8 * 3, progress=False)
    assert resumed["history"] == full["history"]
    assert resumed["env_steps"] == full["env_steps"] == 6 * 8 * 3


# --------------------------------------------------------------------------- exploration that costs
def test_move_cost_lowers_each_glance_s_reward_by_the_distance_travelled(env):
    from ham.learn.evaluation import path_lengths

    _, episode = _episode(env, glances=4)
    q = episode.locations
    travel = (q[1:] - q[:-1]).norm(dim=-1)  # (S-1, B)
    assert torch.allclose(path_lengths(q), travel.sum(0))
    free = info_loss(episode, gamma=1.0)
    costly = info_loss(episode, gamma=1.0, move_cost=0.5, move_cost_on="reward")
    # the classification and the information gain do not change; the critic's targets do
    assert torch.equal(free.classification, costly.classification)
    assert torch.equal(free.gain, costly.gain)
    values = episode.values().detach()
    ret_free = advantages(free.gain[1:], values, 1.0, 1.0)[1]
    ret_cost = advantages(free.gain[1:] - 0.5 * travel, values, 1.0, 1.0)[1]
    assert torch.allclose(((ret_cost - episode.values()) ** 2).sum(0).mean(), costly.critic)
    assert not torch.allclose(ret_free, ret_cost)
    with pytest.raises(HamError, match="move_cost = -1"):
        info_loss(episode, move_cost=-1.0)


def test_move_cost_needs_the_info_learner_and_evaluations_report_the_path(tmp_path):
    with pytest.raises(HamError, match="move_cost = 0.1 with learner 'hybrid'"):
        TrainConfig(move_cost=0.1)
    metrics = train(tiny(move_cost=0.2, move_cost_on="reward"), tmp_path / "run", progress=False)
    assert metrics["path_length"] is not None and metrics["path_length"] >= 0
    assert all("path_length" in row for row in metrics["history"])


@pytest.mark.parametrize("first_glance", ["random", "learned"])
def test_the_mean_move_cost_pulls_each_mean_pose_towards_the_previous_pose(env, first_glance):
    from ham.learn.info_loss import mean_travel_penalty

    model, episode = _episode(env, glances=4, first_glance=first_glance)
    mu = episode.policy.mu[-3:]  # the means of glances 2..4
    hand = 0.5 * (mu - episode.locations[:-1]).norm(dim=-1).sum(0).mean()
    assert torch.allclose(mean_travel_penalty(episode, 0.5), hand)
    free = info_loss(episode, gamma=1.0)
    costly = info_loss(episode, gamma=1.0, move_cost=0.5, move_cost_on="mean")
    # the reward (and so the critic and the policy's REINFORCE term) is that of a free move
    assert torch.equal(free.critic, costly.critic) and torch.equal(free.policy, costly.policy)
    assert torch.allclose(costly.total - free.total, hand)
    model.zero_grad()
    mean_travel_penalty(episode, 0.5).backward()
    trained = {n for n, p in model.named_parameters() if p.grad is not None and p.grad.abs().sum()}
    assert trained and all(n.startswith("location.") for n in trained)
    with pytest.raises(HamError, match="move_cost_on = 'path'"):
        info_loss(episode, move_cost=0.5, move_cost_on="path")


def test_the_move_cost_in_both_places_is_the_reward_s_and_the_mean_penalty(env):
    from ham.learn.info_loss import mean_travel_penalty

    _, episode = _episode(env, glances=4)
    on_reward = info_loss(episode, gamma=1.0, move_cost=0.5, move_cost_on="reward")
    both = info_loss(episode, gamma=1.0, move_cost=0.5, move_cost_on="both")
    assert torch.equal(both.critic, on_reward.critic) and torch.equal(both.policy, on_reward.policy)
    assert torch.allclose(both.total - on_reward.total, mean_travel_penalty(episode, 0.5))


def test_a_run_trains_with_the_mean_move_cost_and_refuses_an_unknown_one(tmp_path):
    with pytest.raises(HamError, match="move_cost_on"):
        tiny(move_cost=0.2, move_cost_on="path")
    metrics = train(tiny(move_cost=0.2, move_cost_on="mean"), tmp_path / "run", progress=False)
    assert metrics["path_length"] is not None and metrics["path_length"] >= 0


# --------------------------------------------------------------------------- several epochs (PPO)
@pytest.mark.parametrize("first_glance", ["random", "learned"])
def test_replay_gives_the_played_episode_and_the_first_pass_gradient_of_info_loss(
    env, first_glance
):
    """The network replayed on a batch's recorded glances gives the played episode's numbers,
    and the clipped loss's first pass (ratio 1) the gradient of :func:`info_loss`."""
    from ham.learn.info_loss import clipped_info_loss, info_targets
    from ham.learn.train import GlanceRecorder

    torch.manual_seed(0)
    model = HapticAttentionModel(HamConfig(glances=4, first_glance=first_glance))
    recorder = GlanceRecorder(env)
    played = model(recorder, env.sample_objects(), torch.Generator().manual_seed(0))
    again = model.replay(
        torch.stack(recorder.pressures), torch.stack(recorder.where), played=played
    )
    assert torch.allclose(again.logits, played.logits, atol=1e-6)
    assert torch.allclose(again.policy.mu, played.policy.mu, atol=1e-6)
    assert again.policy.mu.shape == played.policy.mu.shape

    def grads(loss):
        model.zero_grad()
        loss.backward(retain_graph=True)
        return [None if p.grad is None else p.grad.clone() for p in model.parameters()]

    reference = grads(info_loss(played, 0.7, 0.9, entropy_coef=0.01).total)
    targets = info_targets(played, 0.7, 0.9)
    first = grads(clipped_info_loss(again, targets, 0.2, entropy_coef=0.01).total)
    for a, b in zip(reference, first, strict=True):
        assert (a is None) == (b is None)
        if a is not None:
            assert torch.allclose(a, b, atol=1e-5)


def test_the_clip_stops_the_policy_gradient_beyond_it(env):
    """With every ratio pushed past ``1 + clip`` on positive advantages, the policy term has no
    gradient left; within the clip it has."""
    from ham.learn.info_loss import InfoTargets, clipped_info_loss, info_targets

    model, episode = _episode(env, glances=3)
    t = info_targets(episode)
    pos = t.advantage.abs() + 0.1
    far = InfoTargets(t.old_log_prob - 1.0, pos, t.target)  # ratio = e > 1.2
    near = InfoTargets(t.old_log_prob, pos, t.target)
    for targets, moves in ((far, False), (near, True)):
        model.zero_grad()
        clipped_info_loss(episode, targets, clip=0.2).policy.backward(retain_graph=True)
        grad = model.location.mu.weight.grad
        assert (grad is not None and bool(grad.abs().sum() > 0)) == moves


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(epochs=0), "epochs = 0"),
        (dict(clip=0.0), "clip = 0.0"),
        (dict(epochs=2, learner="hybrid"), "epochs = 2 with learner 'hybrid'"),
        (dict(epochs=2, model=HamConfig(stop=True)), "epochs = 2 with a learned stop"),
        (dict(epochs=2, policy_epochs=3), "policy_epochs = 3"),
        (dict(epochs=2, policy_epochs=0), "policy_epochs = 0"),
    ],
)
def test_bad_epochs(kw, match):
    with pytest.raises(HamError, match=match):
        tiny(**kw)


def test_epochs_take_that_many_optimizer_steps_per_batch(tmp_path):
    from ham.learn.train import Run, train_step

    for epochs in (1, 3):
        run = Run.create(tiny(epochs=epochs))
        train_step(run)
        state = run.optimizer.state_dict()["state"]
        assert {int(s["step"]) for s in state.values()} == {epochs} and run.step == 1
        run.close()
    # policy_epochs: the location network steps on the first pass only, the rest on all three
    run = Run.create(tiny(epochs=3, policy_epochs=1))
    train_step(run)
    policy = {id(p) for p in run.agent.location.parameters()}
    steps = {
        id(p): int(run.optimizer.state[p]["step"])
        for p in run.agent.parameters()
        if p in run.optimizer.state
    }
    assert {steps[i] for i in policy} == {1}
    assert {v for i, v in steps.items() if i not in policy} == {3}
    run.close()
    out = train(tiny(epochs=3, steps=4), tmp_path / "e3", progress=False)
    assert out["steps"] == 4 and out["config"]["epochs"] == 3


# --------------------------------------------------------------------------- the centered glimpse
def test_centered_glimpse_is_the_glimpse_minus_its_mean_and_the_mean(tmp_path, ham_cli):
    pytest.importorskip("ap_gym", exc_type=ImportError)
    from ham.learn.ap_adapter import CENTER_GAIN, ApGymConfig, ApGymGlanceEnv
    from ham.learn.train import fit_to_ap_gym

    cs = "ap_gym:CircleSquare-v0"
    flat = ApGymGlanceEnv(cs, 4, actions="relative", seed=1)
    centered = ApGymGlanceEnv(cs, 4, actions="relative", seed=1, glimpse="centered")
    assert (flat.pressure_dim, centered.pressure_dim) == (25, 26)
    q = torch.full((4, 2), 0.5)
    for env in (flat, centered):
        env.sample_objects()
    for _ in range(2):
        raw, x = flat.glance(None, q), centered.glance(None, q)
        mean = raw.mean(-1, keepdim=True)
        assert torch.allclose(x, torch.cat([(raw - mean) * CENTER_GAIN, mean], -1), atol=1e-6)
    flat.close()
    centered.close()
    with pytest.raises(HamError, match="normalization = 'l2' with a centered glimpse"):
        ApGymGlanceEnv(cs, 4, normalization="l2", glimpse="centered")
    with pytest.raises(HamError, match="glimpse = 'round'"):
        ApGymConfig(cs, glimpse="round")
    config = fit_to_ap_gym(TrainConfig(), ApGymConfig(cs, actions="relative", glimpse="centered"))
    assert config.model.pressure_dim == 26
    p = ham_cli("train", "--glimpse", "centered", "--steps", "1", "--out", str(tmp_path / "x"))
    assert p.returncode == 2 and "--glimpse apply only with --env" in p.stderr
