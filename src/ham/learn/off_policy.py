"""The off-policy learner (``--learner sac``): the information learner's classifier, and a
soft actor-critic for the location policy over replayed episodes.

Beyond the paper, after the published agents that search best (the APPLE study's SAC and
CrossQ: an off-policy critic over replayed glances, a prediction head trained by supervision).
Each training step plays one fresh batch with the location policy (sampled poses) and stores its
episodes whole in a replay buffer: the glances (the observations: pressures or glimpses, the
where-inputs the network read, contact heights where it reads them), the poses the policy chose
(its actions) and the classes. Then ``sac_updates`` times a batch of ``replay_batch`` episodes
is drawn from the buffer and the network as it is now replayed over their stored glances
(a recurrent or transformer core's state is recomputed, never stored: the simplest sound replay
of a recurrent agent), and:

* the classifier (tactile network, core, classifier head) takes one step on the cross-entropy
  after every glance, as the information learner (:mod:`ham.learn.info_loss`);
* the reward of glance ``s`` is the information it gains, ``r_s = CE_{s-1} - CE_s`` (``CE_0 =
  log K``), recomputed with the classifier as it is now (the classifier changes; the reward
  of an old episode is today's);
* a twin Q critic ``Q_i(tau, q)`` over the core output ``tau`` (detached) and the pose ``q``
  regresses the soft TD target ``y = r + gamma (1 - done) (min_i Q'_i(tau', q') - alpha log
  pi(q' | tau'))``, ``q' ~ pi(. | tau')``, with target critics ``Q'`` tracking ``Q`` by Polyak
  averaging (``target_tau``); the last glance ends the episode (``done``);
* the actor is the HAM's own location network (its Gaussian truncated to ``[-1, 1]``, the
  paper's policy; evaluation still takes its mean pose): it minimizes ``alpha log pi(q | tau)
  - min_i Q_i(tau, q)`` with ``q`` drawn by the reparametrized inverse-CDF sample of the
  truncated Gaussian and ``log pi`` its exact truncated density;
* the entropy temperature ``alpha`` is tuned to keep the policy's entropy near
  ``target_entropy`` (default ``-k`` for ``k`` pose dims, SAC's choice): ``L = -log alpha
  (log pi + target_entropy)``.

The parts train disjoint weights: the classification the tactile network, the core and the
classifier; the actor's loss only the location network (it reads ``tau`` detached, and the
critic's weights are frozen while it is taken); the critic's loss only the critic; the
temperature's only ``log alpha``. The baseline head is not used. The critics, their targets,
``log alpha``, their optimizers, the buffer and the generator of replay draws and action noise
are all in the checkpoint: a resumed run is bit-identical.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import nn
from torch.nn import functional as F

from ham.errors import DivergedError, HamError
from ham.learn.info_loss import GainLoss, information_gain
from ham.model.agent import HapticAttentionModel
from ham.model.policy import LocationDistribution, SquashedGaussian, TruncatedGaussian

#: the critic's hidden layers (two of 256 ReLU units, SAC's and APPLE's size)
CRITIC_UNITS = 256
#: float64 below this probability mass of the truncated Gaussian's interval is treated as this
_MIN_MASS = 1e-12


# --------------------------------------------------------------------------- the policy's density
def _bounds(mu: torch.Tensor, sigma: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``Phi((-1 - mu) / sigma)`` and ``Phi((1 - mu) / sigma)`` in float64."""
    m, s = mu.double(), sigma.double()
    return torch.special.ndtr((-1 - m) / s), torch.special.ndtr((1 - m) / s)


def truncated_log_prob(q: torch.Tensor, mu: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """``log pi(q)`` of ``N(mu, sigma)`` truncated to ``[-1, 1]``, per stream, summed over the
    last axis: the untruncated density less ``log (Phi(b) - Phi(a))`` (exact, unlike the
    paper's REINFORCE eligibilities, which take the untruncated one)."""
    a, b = _bounds(mu, sigma)
    m, s, x = mu.double(), sigma.double(), q.double()
    log_n = -torch.log(s) - 0.5 * ((x - m) / s) ** 2 - 0.5 * math.log(2 * math.pi)
    mass = (b - a).clamp_min(_MIN_MASS)
    return (log_n - torch.log(mass)).sum(-1).to(mu.dtype)


def truncated_rsample(
    mu: torch.Tensor, sigma: torch.Tensor, generator: torch.Generator | None
) -> tuple[torch.Tensor, torch.Tensor]:
    """A reparametrized sample ``q`` of ``N(mu, sigma)`` truncated to ``[-1, 1]`` and its
    ``log pi(q)`` (summed over the last axis): ``q = mu + sigma Phi^-1(Phi(a) + u (Phi(b) -
    Phi(a)))``, ``u ~ U(0, 1)``, differentiable in ``mu`` and ``sigma`` (float64 inside)."""
    a, b = _bounds(mu, sigma)
    u = torch.rand(mu.shape, generator=generator, dtype=torch.float64, device=mu.device)
    # keep the quantile strictly inside (0, 1): ndtri is infinite at the ends
    p = (a + u * (b - a)).clamp(1e-15, 1 - 1e-15)
    q = (mu.double() + sigma.double() * torch.special.ndtri(p)).clamp(-1, 1).to(mu.dtype)
    return q, truncated_log_prob(q, mu, sigma)


def policy_rsample(
    dist: LocationDistribution, generator: torch.Generator | None
) -> tuple[torch.Tensor, torch.Tensor]:
    """A reparametrized pose and its ``log pi`` from the location policy's distribution: the
    squashed Gaussian's own (``--policy squashed``), or the truncated Gaussian's inverse-CDF
    sample (``learned``: its gradient fades as ``sigma`` grows, docs/learners.md)."""
    if isinstance(dist, SquashedGaussian):
        return dist.rsample(generator)
    if isinstance(dist, TruncatedGaussian):
        return truncated_rsample(dist.mu, dist.sigma, generator)
    raise HamError(
        f"a {type(dist).__name__} location policy with learner 'sac'; accepted: --policy "
        "squashed or learned (a reparametrized sample)"
    )


# --------------------------------------------------------------------------- the critic
class TwinQ(nn.Module):
    """Two critics ``Q_i(tau, q)``: MLPs ``[tau, q] -> 256 ReLU -> 256 ReLU -> 1``."""

    def __init__(self, state_units: int, pose_dims: int, units: int = CRITIC_UNITS) -> None:
        super().__init__()

        def mlp() -> nn.Sequential:
            return nn.Sequential(
                nn.Linear(state_units + pose_dims, units), nn.ReLU(),
                nn.Linear(units, units), nn.ReLU(),
                nn.Linear(units, 1),
            )  # fmt: skip

        self.q1, self.q2 = mlp(), mlp()

    def forward(self, tau: torch.Tensor, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.cat([tau, q], -1)
        return self.q1(x).squeeze(-1), self.q2(x).squeeze(-1)


# --------------------------------------------------------------------------- the replay buffer
class ReplayBuffer:
    """Whole episodes, oldest overwritten first: ``pressures`` ``(N, S, D)``, ``where``
    ``(N, S, w)`` (the where-inputs the network read), ``locations`` ``(N, S, k)`` (the poses
    asked for: the policy's actions), ``objects`` ``(N,)`` and, where the model reads them,
    ``heights`` ``(N, S)``. Storage is allocated at the first episodes (their sizes)."""

    def __init__(self, capacity: int) -> None:
        if not (isinstance(capacity, int) and not isinstance(capacity, bool) and capacity >= 1):
            raise HamError(f"replay_size = {capacity!r}; accepted: an integer >= 1")
        self.capacity = capacity
        self.data: dict[str, torch.Tensor] = {}
        self.size = 0
        self.next = 0

    def add(self, **episodes: torch.Tensor | None) -> None:
        """Store a batch: each tensor has the batch first (``objects`` ``(B,)``, the rest
        ``(B, S, ...)``); ``None`` entries are not stored."""
        items = {k: v.detach() for k, v in episodes.items() if v is not None}
        batch = items["objects"].shape[0]
        if not self.data:
            self.data = {
                k: v.new_zeros((self.capacity, *v.shape[1:])) for k, v in items.items()
            }  # fmt: skip
        idx = (self.next + torch.arange(batch, device=items["objects"].device)) % self.capacity
        for k, v in items.items():
            self.data[k][idx] = v
        self.next = (self.next + batch) % self.capacity
        self.size = min(self.capacity, self.size + batch)

    def sample(self, n: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
        """``n`` stored episodes drawn uniformly, with replacement."""
        device = self.data["objects"].device
        idx = torch.randint(self.size, (n,), generator=generator, device=device)
        return {k: v[idx] for k, v in self.data.items()}

    def state_dict(self) -> dict:
        # only what is filled: a young run's checkpoint stays small
        return {
            "capacity": self.capacity,
            "size": self.size,
            "next": self.next,
            "data": {k: v[: self.size].clone() for k, v in self.data.items()},
        }

    def load_state_dict(self, state: dict) -> None:
        if int(state["capacity"]) != self.capacity:
            raise HamError(
                f"the checkpoint's replay buffer holds {state['capacity']} episodes but the "
                f"config says replay_size = {self.capacity}; accepted: the run's own"
            )
        self.size, self.next = int(state["size"]), int(state["next"])
        self.data = {}
        for k, v in state["data"].items():
            full = v.new_zeros((self.capacity, *v.shape[1:]))
            full[: v.shape[0]] = v
            self.data[k] = full


# --------------------------------------------------------------------------- the learner's state
class SacState:
    """What the SAC learner keeps beside the HAM: the critics and their targets, ``log alpha``,
    their optimizers (Adam, at the run's learning rate), the replay buffer and its generator
    (replay draws and action noise; seed stream 3 of the run)."""

    def __init__(self, agent: HapticAttentionModel, config, device: torch.device) -> None:
        # created after the HAM's weights (torch's global generator, seeded by the run): the
        # HAM starts as it does with every other learner
        c = config
        self.critic = TwinQ(agent.config.hidden_units, len(agent.config.pose_dims)).to(device)
        self.target = copy.deepcopy(self.critic)
        for p in self.target.parameters():
            p.requires_grad_(False)
        self.log_alpha = torch.tensor(math.log(c.init_alpha), device=device, requires_grad=True)
        betas = (c.momentum, 0.999)
        self.critic_optimizer = torch.optim.Adam(self.critic.parameters(), lr=c.lr, betas=betas)
        self.alpha_optimizer = torch.optim.Adam([self.log_alpha], lr=c.lr, betas=betas)
        self.buffer = ReplayBuffer(c.replay_size)
        self.generator = torch.Generator(device=device)
        self.generator.manual_seed(c.seed * 1000 + 3)
        dims = len(agent.config.pose_dims)
        self.target_entropy = float(-dims if c.target_entropy is None else c.target_entropy)

    def set_lr(self, lr: float) -> None:
        for opt in (self.critic_optimizer, self.alpha_optimizer):
            for group in opt.param_groups:
                group["lr"] = lr

    def state_dict(self) -> dict:
        return {
            "critic": self.critic.state_dict(),
            "target": self.target.state_dict(),
            "log_alpha": self.log_alpha.detach().clone(),
            "critic_optimizer": self.critic_optimizer.state_dict(),
            "alpha_optimizer": self.alpha_optimizer.state_dict(),
            "buffer": self.buffer.state_dict(),
            "generator": self.generator.get_state(),
        }

    def load_state_dict(self, state: dict) -> None:
        self.critic.load_state_dict(state["critic"])
        self.target.load_state_dict(state["target"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.critic_optimizer.load_state_dict(state["critic_optimizer"])
        self.alpha_optimizer.load_state_dict(state["alpha_optimizer"])
        self.buffer.load_state_dict(state["buffer"])
        self.generator.set_state(state["generator"])


# --------------------------------------------------------------------------- one update
@dataclass
class SacLoss(GainLoss):
    """The parts of one SAC update (scalars; ``gain`` ``(S, B)`` of the replayed episodes).
    ``total`` is what the HAM's optimizer minimizes (classification + actor); ``alpha`` is the
    temperature's loss; ``entropy`` the policy's, estimated by ``-log pi`` of its samples."""

    total: torch.Tensor
    classification: torch.Tensor
    actor: torch.Tensor
    critic: torch.Tensor
    alpha: torch.Tensor
    entropy: torch.Tensor
    gain: torch.Tensor

    POLICY_PART: ClassVar[str] = "actor"


def replay_states(
    agent: HapticAttentionModel,
    pressures: torch.Tensor,
    where: torch.Tensor,
    heights: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The network as it is now over stored glances ``(S, B, D)`` at where-inputs ``(S, B, w)``:
    the logits ``(S, B, K)`` and core outputs ``tau_{1:s}`` ``(S, B, H)`` after each glance."""
    state = agent.core.initial_state(pressures.shape[1], pressures)
    logits, taus = [], []
    for s in range(pressures.shape[0]):
        h = None if heights is None else heights[s]
        tau, state = agent.step(pressures[s], where[s], state, h)
        taus.append(tau)
        logits.append(agent.classifier(tau))
    return torch.stack(logits), torch.stack(taus)


def sac_losses(
    agent: HapticAttentionModel,
    sac: SacState,
    episodes: dict[str, torch.Tensor],
    gamma: float,
    critic_trains_core: bool = False,
) -> SacLoss:
    """The losses of one update on stored ``episodes`` (:meth:`ReplayBuffer.sample`), with their
    graphs: ``classification`` (+ ``actor``) for the HAM's optimizer, ``critic`` and ``alpha``
    (the temperature's loss) for theirs. Action noise comes from the learner's generator.

    ``critic_trains_core``: the critic's loss also trains the tactile network and the core (it
    reads ``tau`` undetached; its TD targets stay detached), so that the state the location
    network reads holds what the value needs, not only what the classification needs (the
    encoder trained by the critic, the actor on its detached output: SAC-AE's and DrQ's way)."""
    pressures = episodes["pressures"].transpose(0, 1)  # (S, B, D)
    where = episodes["where"].transpose(0, 1)
    heights = episodes["heights"].transpose(0, 1) if "heights" in episodes else None
    actions = episodes["locations"].transpose(0, 1)  # (S, B, k)
    objects = episodes["objects"]
    logits, taus = replay_states(agent, pressures, where, heights)
    s, b, k = logits.shape
    classification = (
        F.cross_entropy(logits.reshape(s * b, k), objects.repeat(s), reduction="mean") * s
    )
    gain = information_gain(logits, objects)  # (S, B), detached
    live, taus = taus, taus.detach()
    if agent.config.first_glance == "learned":  # tau_0 = 0 chose the first glance
        states = torch.cat([torch.zeros_like(taus[:1]), taus[:-1]])
        live = torch.cat([torch.zeros_like(taus[:1]), live[:-1]])
        acts, rewards = actions, gain
    else:
        states, live, acts, rewards = taus[:-1], live[:-1], actions[1:], gain[1:]
    next_states = taus[-states.shape[0] :]  # tau after the chosen glance
    done = torch.zeros_like(rewards)
    done[-1] = 1.0  # the last glance ends the episode: nothing follows it
    alpha = sac.log_alpha.detach().exp()

    # the critic: the soft TD target from the target critics and a fresh action
    with torch.no_grad():
        q2, logp2 = policy_rsample(agent.location.distribution(next_states), sac.generator)
        t1, t2 = sac.target(next_states, q2)
        y = rewards + gamma * (1 - done) * (torch.minimum(t1, t2) - alpha * logp2)
    c1, c2 = sac.critic(live if critic_trains_core else states, acts)
    critic_loss = 0.5 * ((c1 - y) ** 2).mean() + 0.5 * ((c2 - y) ** 2).mean()

    # the actor: the location network, the critic's weights frozen
    for p in sac.critic.parameters():
        p.requires_grad_(False)
    try:
        q, logp = policy_rsample(agent.location.distribution(states), sac.generator)
        a1, a2 = sac.critic(states, q)
        actor_loss = (alpha * logp - torch.minimum(a1, a2)).mean()
    finally:
        for p in sac.critic.parameters():
            p.requires_grad_(True)
    alpha_loss = -(sac.log_alpha * (logp.detach() + sac.target_entropy)).mean()
    return SacLoss(
        total=classification + actor_loss,
        classification=classification,
        actor=actor_loss,
        critic=critic_loss,
        alpha=alpha_loss,
        entropy=-logp.detach().mean(),
        gain=gain,
    )


def sac_update(
    agent: HapticAttentionModel,
    optimizer: torch.optim.Optimizer,
    sac: SacState,
    batch: int,
    gamma: float,
    target_tau: float,
    critic_trains_core: bool = False,
) -> SacLoss:
    """One update on ``batch`` episodes drawn from the buffer (:func:`sac_losses`): the HAM's
    optimizer steps on the classification and the actor's loss, the critic's and the
    temperature's on theirs; the target critics move ``target_tau`` towards the critics.
    Returns the losses, detached."""
    episodes = sac.buffer.sample(batch, sac.generator)
    loss = sac_losses(agent, sac, episodes, gamma, critic_trains_core)
    for name in ("total", "critic", "alpha"):
        v = getattr(loss, name)
        if not bool(torch.isfinite(v)):
            raise DivergedError(f"the sac learner diverged: its {name} loss is {v.item()}")
    optimizer.zero_grad(set_to_none=True)
    sac.critic_optimizer.zero_grad(set_to_none=True)
    sac.alpha_optimizer.zero_grad(set_to_none=True)
    # one backward pass: with critic_trains_core both reach the core through one graph
    (loss.total + loss.critic).backward()
    loss.alpha.backward()
    optimizer.step()
    sac.critic_optimizer.step()
    sac.alpha_optimizer.step()
    with torch.no_grad():
        for p, t in zip(sac.critic.parameters(), sac.target.parameters(), strict=True):
            t.mul_(1 - target_tau).add_(p, alpha=target_tau)
    return SacLoss(
        **{
            k: getattr(loss, k).detach()
            for k in ("total", "classification", "actor", "critic", "alpha", "entropy", "gain")
        }  # fmt: skip
    )
