"""The hybrid loss: its gradients are the paper's eligibilities; what is detached from what."""

from __future__ import annotations

import pytest
import torch

from ham.errors import HamError
from ham.learn.hybrid_loss import hybrid_loss, reinforce_term, returns, reward
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.model.location_net import gaussian_log_prob
from ham.model.policy import TruncatedGaussian


def zeta_mu(q, mu, sigma):
    """Eq reinforce_mean."""
    return (q - mu) / sigma**2


def zeta_sigma(q, mu, sigma):
    """Eq reinforce_std."""
    return ((q - mu) ** 2 - sigma**2) / sigma**3


def _episode(env, objects_seed: int | None = None, **kw):
    if objects_seed is not None:  # the batch's objects this seed's, not the module's earlier draws
        env.generator.manual_seed(objects_seed)
    torch.manual_seed(0)
    model = HapticAttentionModel(HamConfig(glances=3, **kw))
    episode = model(env, env.sample_objects(), torch.Generator().manual_seed(0))
    return model, episode


# --------------------------------------------------------------------------- the eligibilities
def test_log_density_gradients_are_the_eligibilities():
    g = torch.Generator().manual_seed(0)
    q = torch.rand(50, 2, generator=g, dtype=torch.float64) * 2 - 1
    mu = (torch.rand(50, 2, generator=g, dtype=torch.float64) * 2 - 1).requires_grad_()
    sigma = (torch.rand(50, 2, generator=g, dtype=torch.float64) + 0.05).requires_grad_()
    gaussian_log_prob(q, mu, sigma).sum().backward()
    assert torch.allclose(mu.grad, zeta_mu(q, mu, sigma))
    assert torch.allclose(sigma.grad, zeta_sigma(q, mu, sigma))
    # and the density is the Gaussian's
    ref = torch.distributions.Normal(mu, sigma).log_prob(q)
    assert torch.allclose(gaussian_log_prob(q, mu, sigma), ref)


def test_reinforce_gradient_is_minus_advantage_times_eligibility_numerically():
    """d/dmu and d/dsigma of the REINFORCE term, by central differences, equal
    -(r - b) * zeta / B: the paper's update (Eq update_weights) for the policy's outputs."""
    g = torch.Generator().manual_seed(1)
    s, b = 2, 5
    q = torch.rand(s, b, 2, generator=g, dtype=torch.float64) * 2 - 1
    mu = torch.rand(s, b, 2, generator=g, dtype=torch.float64) * 2 - 1
    sigma = torch.rand(s, b, 2, generator=g, dtype=torch.float64) * 0.8 + 0.1
    adv = torch.rand(s, b, generator=g, dtype=torch.float64) * 2 - 1
    eps = 1e-6
    for name, zeta in (("mu", zeta_mu), ("sigma", zeta_sigma)):
        expected = -adv[..., None] * zeta(q, mu, sigma) / b
        numeric = torch.zeros_like(mu)
        for idx in torch.cartesian_prod(*(torch.arange(n) for n in mu.shape)):
            i = tuple(idx.tolist())
            plus, minus = mu.clone(), mu.clone()
            splus, sminus = sigma.clone(), sigma.clone()
            if name == "mu":
                plus[i] += eps
                minus[i] -= eps
                f1 = reinforce_term(q, TruncatedGaussian(plus, sigma), adv)
                f0 = reinforce_term(q, TruncatedGaussian(minus, sigma), adv)
            else:
                splus[i] += eps
                sminus[i] -= eps
                f1 = reinforce_term(q, TruncatedGaussian(mu, splus), adv)
                f0 = reinforce_term(q, TruncatedGaussian(mu, sminus), adv)
            numeric[i] = (f1 - f0) / (2 * eps)
        assert torch.allclose(numeric, expected, rtol=1e-5, atol=1e-7), name


@pytest.mark.parametrize("reduction", ["sum", "mean"])
def test_hybrid_loss_policy_gradient_matches_the_paper(env, reduction):
    """d(loss)/d(mu, sigma) = -beta * (r - b) * zeta per episode (summed, or averaged)."""
    model, ep = _episode(env)
    mu = ep.policy.mu.detach().requires_grad_()
    sigma = ep.policy.sigma.detach().requires_grad_()
    ep.policy = TruncatedGaussian(mu, sigma)
    loss = hybrid_loss(ep, beta=0.4, reinforce_reduction=reduction)
    loss.total.backward()
    r = reward(ep.logits[-1], ep.objects)
    adv = (r[None] - ep.baselines[:-1]).detach()[..., None]
    q = ep.locations[1:]
    scale = 1.0 if reduction == "sum" else 1.0 / ep.objects.shape[0]
    assert torch.allclose(mu.grad, -0.4 * adv * zeta_mu(q, mu, sigma) * scale, atol=1e-6)
    assert torch.allclose(sigma.grad, -0.4 * adv * zeta_sigma(q, mu, sigma) * scale, atol=1e-6)


def test_reward_is_argmax_correct():
    logits = torch.tensor([[2.0, 1.0], [0.0, 3.0], [5.0, -1.0]])
    assert reward(logits, torch.tensor([0, 0, 0])).tolist() == [1.0, 0.0, 1.0]


def test_sum_reduction_is_batch_times_mean(env):
    _, ep = _episode(env)
    mean = hybrid_loss(ep, classification_reduction="mean", reinforce_reduction="mean")
    total = hybrid_loss(ep, classification_reduction="sum", reinforce_reduction="sum")
    b = ep.objects.shape[0]
    assert torch.allclose(total.classification, b * mean.classification)
    assert torch.allclose(total.reinforce, b * mean.reinforce)
    assert torch.allclose(total.baseline, mean.baseline)  # the baseline's MSE is always a mean
    default = hybrid_loss(ep)  # classification summed, REINFORCE averaged
    assert torch.allclose(default.classification, total.classification)
    assert torch.allclose(default.reinforce, mean.reinforce)
    with pytest.raises(HamError, match="reinforce_reduction"):
        hybrid_loss(ep, reinforce_reduction="max")


def test_all_glances_classification_averages_every_glance(env):
    # APPLE's HAM trains the prediction after every glance: the mean over the glances of each
    # glance's cross-entropy, summed or averaged over the batch; the rest of the loss is unchanged
    _, ep = _episode(env)
    last = hybrid_loss(ep)
    for reduction in ("sum", "mean"):
        every = hybrid_loss(ep, classification_reduction=reduction, classification_glances="all")
        per_glance = [
            torch.nn.functional.cross_entropy(g, ep.objects, reduction=reduction) for g in ep.logits
        ]
        assert len(per_glance) == ep.logits.shape[0] > 1
        assert torch.allclose(every.classification, torch.stack(per_glance).mean())
        assert not torch.allclose(every.classification, per_glance[-1])
        assert torch.equal(every.reward, last.reward)  # the reward stays the last glance's
        assert torch.allclose(every.reinforce, last.reinforce)
    with pytest.raises(HamError, match="classification_glances 'first'; accepted: last, all"):
        hybrid_loss(ep, classification_glances="first")


def test_baseline_loss_covers_every_sub_sequence(env):
    _, ep = _episode(env)
    loss = hybrid_loss(ep)
    r = reward(ep.logits[-1], ep.objects)
    expected = ((r[None] - ep.baselines) ** 2).sum(0).mean()
    assert torch.allclose(loss.baseline, expected)


# --------------------------------------------------------------------------- what is detached
def _grads(model) -> dict[str, float]:
    return {
        n: (0.0 if p.grad is None else p.grad.abs().sum().item())
        for n, p in model.named_parameters()
    }


def _nonzero(grads: dict[str, float], prefix: str) -> bool:
    return any(v > 0 for n, v in grads.items() if n.startswith(prefix))


def test_sampled_locations_carry_no_gradient(env):
    _, ep = _episode(env)
    assert not ep.locations.requires_grad
    assert ep.policy.mu.requires_grad and ep.policy.sigma.requires_grad


def test_reinforce_term_trains_only_the_location_network(env):
    model, ep = _episode(env)
    loss = hybrid_loss(ep)
    loss.reinforce.backward()
    g = _grads(model)
    assert _nonzero(g, "location.")
    for part in ("tactile.", "core.", "classifier.", "baseline."):
        assert not _nonzero(g, part), part  # the baseline in the advantage is detached too


def test_baseline_loss_trains_only_the_baseline(env):
    model, ep = _episode(env)
    hybrid_loss(ep).baseline.backward()
    g = _grads(model)
    assert _nonzero(g, "baseline.")
    for part in ("tactile.", "core.", "classifier.", "location."):
        assert not _nonzero(g, part), part  # the core gets no gradient from Eq baseline


def test_classification_trains_tactile_core_classifier_only(env):
    model, ep = _episode(env)
    hybrid_loss(ep).classification.backward()
    g = _grads(model)
    for part in ("tactile.", "core.", "classifier."):
        assert _nonzero(g, part), part
    for part in ("location.", "baseline."):
        assert not _nonzero(g, part), part


def test_random_policy_has_no_reinforce_term(env):
    model, ep = _episode(env, policy="random")
    loss = hybrid_loss(ep, beta=0.4)
    assert loss.reinforce.item() == 0.0
    loss.total.backward()
    assert torch.isfinite(loss.total)


def test_beta_zero_drops_the_reinforce_term(env):
    _, ep = _episode(env)
    a, b = hybrid_loss(ep, beta=0.0), hybrid_loss(ep, beta=0.4)
    assert torch.allclose(a.total, a.classification + a.baseline)
    assert not torch.allclose(b.total, a.total) or b.reinforce.item() == 0.0


# --------------------------------------------------------------------------- per-glance rewards
def test_returns_by_hand():
    # 3 glances, 2 episodes: episode 0 (object 0) right after glances 1 and 3, episode 1 (object
    # 1) after glance 2
    says_0, says_1 = [3.0, 0.0], [0.0, 3.0]
    logits = torch.tensor([[says_0, says_0], [says_1, says_1], [says_0, says_0]])
    objects = torch.tensor([0, 1])
    assert returns(logits, objects, "all", 0.5).tolist() == [
        [1 + 0.5 * 0 + 0.25 * 1, 0 + 0.5 * 1 + 0.25 * 0],  # R_1 = r_1 + g r_2 + g^2 r_3
        [0 + 0.5 * 1, 1 + 0.5 * 0],
        [1.0, 0.0],
    ]
    assert returns(logits, objects, "last", 0.5).tolist() == [[0.25, 0.0], [0.5, 0.0], [1, 0]]
    assert returns(logits, objects, "last", 1.0).tolist() == [[1.0, 0.0]] * 3  # the paper's r


@pytest.mark.parametrize("first_glance", ["random", "learned"])
def test_per_glance_reward_credits_each_pose_with_its_return(env, first_glance):
    # the pose q_{s+1}, chosen from tau_{1:s}, earns R_s; a learned first pose gamma * R_1; each
    # baseline learns the return of its state; the classification term is not touched. It needs
    # a batch where the last glance and an earlier one each predict some object right (with no
    # reward at all, every loss below is the paper's): the first objects seed that gives one
    for seed in range(20):
        _, ep = _episode(env, objects_seed=seed, first_glance=first_glance)
        right = ep.logits.argmax(-1) == ep.objects
        if bool(right[-1].any() and right[:-1].any()):
            break
    ret = returns(ep.logits, ep.objects, "all", 0.9)
    loss = hybrid_loss(ep, reward_glances="all", reward_discount=0.9)
    earned = ret[:-1]
    expected_b = ((ret - ep.baselines) ** 2).sum(0).mean()
    if first_glance == "learned":
        earned = torch.cat([0.9 * ret[:1], earned])
        expected_b = expected_b + ((0.9 * ret[0] - ep.first_baseline) ** 2).mean()
    assert earned.shape == ep.values().shape
    expected_r = reinforce_term(ep.locations[ep.chosen], ep.policy, earned - ep.values())
    assert torch.allclose(loss.reinforce, expected_r)
    assert torch.allclose(loss.baseline, expected_b)
    paper = hybrid_loss(ep)
    assert not torch.allclose(loss.reinforce, paper.reinforce)
    assert torch.equal(loss.classification, paper.classification)
    assert torch.equal(loss.reward, paper.reward)  # the reported reward: the last prediction's
    # the last glance's reward discounted: pose q_{s+1} earns gamma^(S-s) r
    last = hybrid_loss(ep, reward_discount=0.5)
    ret = returns(ep.logits, ep.objects, "last", 0.5)
    earned = ret[:-1] if first_glance == "random" else torch.cat([0.5 * ret[:1], ret[:-1]])
    expected_r = reinforce_term(ep.locations[ep.chosen], ep.policy, earned - ep.values())
    assert torch.allclose(last.reinforce, expected_r)
    assert not torch.allclose(last.reinforce, paper.reinforce)


@pytest.mark.parametrize("first_glance", ["random", "learned"])
def test_a_mean_over_the_glances_divides_each_sum_by_its_terms(env, first_glance):
    # APPLE's policy and value losses are means over the steps: the REINFORCE term over the
    # policy's poses (S - 1, or S with a learned first glance), the baseline loss over its terms
    # (S, or S + 1 with b(tau_0))
    _, ep = _episode(env, first_glance=first_glance)
    kw = dict(reward_glances="all", reward_discount=0.9)
    summed = hybrid_loss(ep, **kw)
    mean = hybrid_loss(ep, glance_reduction="mean", **kw)
    poses = 3 if first_glance == "learned" else 2
    assert torch.allclose(mean.reinforce, summed.reinforce / poses)
    assert torch.allclose(mean.baseline, summed.baseline / (poses + 1))
    assert torch.equal(mean.classification, summed.classification)
    assert torch.allclose(mean.total, mean.classification + 0.4 * mean.reinforce + mean.baseline)
    with pytest.raises(HamError, match="glance_reduction 'median'; accepted: sum, mean"):
        hybrid_loss(ep, glance_reduction="median")


def test_bad_reward_options_are_named(env):
    _, ep = _episode(env)
    with pytest.raises(HamError, match="reward_glances 'first'; accepted: last, all"):
        hybrid_loss(ep, reward_glances="first")
    for bad in (1.5, -0.1, True):
        with pytest.raises(
            HamError, match=rf"reward_discount {bad!r}; accepted: a number in \[0, 1\]"
        ):
            hybrid_loss(ep, reward_discount=bad)
