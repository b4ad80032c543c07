"""Location policies behind one interface: where the next glance goes.

A policy is a module ``distribution(tau) -> LocationDistribution``; the distribution answers
``sample(generator)``, ``log_prob(q)``, ``mode()``, ``entropy()`` and ``scale()`` over poses
``q in [-1, 1]^k`` (``k = 2``, ``(q_x, q_phi)``, in the paper; one stream per pose dimension of
``HamConfig.pose_dims``). The model samples from it, the hybrid loss (:mod:`ham.learn.hybrid_loss`)
takes ``log_prob`` for the REINFORCE term and the evaluation (:mod:`ham.learn.evaluation`) takes
``mode`` for its mean poses, so neither knows what parametrizes a policy. A new policy is one
new :class:`LocationPolicy` subclass registered under a name with :func:`register_policy`;
``HamConfig(policy=NAME)`` (``ham train --policy NAME``) picks it.

Registered:

* ``learned`` (:class:`GaussianPolicy`): the paper's location network, ``pi(q | tau) =
  N(q; mu(tau), sigma(tau))`` per stream ``x`` and ``phi``, sampled truncated to ``[-1, 1]``
  (section "The Location Network"); its parameters are trained by REINFORCE;
* ``random`` (:class:`UniformPolicy`): poses uniform in ``[-1, 1]^2``, the paper's
  random-location model ``pi_rloc``; no weights, no REINFORCE term;
* ``squashed`` (:class:`SquashedGaussianPolicy`, beyond the paper): the location network's
  weights as soft actor-critic's ``tanh``-squashed Gaussian (``--learner sac``);
* ``grid`` (:class:`GridPolicy`, beyond the paper): a fixed systematic sweep, the same poses
  (or moves) at the same glance for every episode; no weights, no REINFORCE term;
* ``grid-corner`` (:class:`CornerGridPolicy`, beyond the paper; ap_gym's ``relative`` actions):
  reads where the glimpse is, goes to the nearest image corner, then sweeps columns 0.5 apart
  (APPLE's grid, in our words); no weights, no REINFORCE term.

A policy may depend on the glance it chooses: the model asks for
``distribution_at(tau, glance)`` (glance index ``s``, 0-based, of the glance to be chosen); the
base class ignores the index and returns ``distribution(tau)``, so only ``grid`` reads it. The
model passes ``position`` too, where the sensor is now (``(B, k)``, the where-input of the last
glance); only ``grid-corner`` reads it.

The distributions are batched: the model stacks one per glance (:meth:`LocationDistribution.stack`),
so ``log_prob`` of the episode's poses ``(S-1, B, k)`` is ``(S-1, B)``: summed over the streams.
"""

from __future__ import annotations

import itertools
import math
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ham.errors import HamError, check_new_name, checked_arguments
from ham.model.location_net import (
    LocationNetwork,
    gaussian_log_prob,
    truncated_normal,
)

#: ``0.5 * log(2 pi e)``: the entropy of a unit Gaussian
_HALF_LOG_2PI_E = 0.5 * math.log(2 * math.pi * math.e)


class LocationDistribution:
    """A batch of distributions over poses ``q in [-1, 1]^2``; the last axis is ``(x, phi)``.

    ``trainable``: its parameters carry a gradient, and the hybrid loss adds a REINFORCE term
    for it (``False``: no term, whatever ``log_prob`` says).
    """

    trainable: ClassVar[bool] = False

    @property
    def batch_shape(self) -> torch.Size:
        raise NotImplementedError

    def sample(self, generator: torch.Generator | None) -> torch.Tensor:
        """Poses ``(*batch_shape, 2)`` drawn from ``generator``, detached, inside ``[-1, 1]``."""
        raise NotImplementedError

    def log_prob(self, q: torch.Tensor) -> torch.Tensor:
        """``log pi(q)`` ``(*batch_shape)``: summed over ``x`` and ``phi``; differentiable in the
        policy's parameters (not in ``q``)."""
        raise NotImplementedError

    def mode(self) -> torch.Tensor | None:
        """The most likely poses ``(*batch_shape, 2)``, detached; ``None`` when there is no
        single one (a uniform distribution)."""
        raise NotImplementedError

    def entropy(self) -> torch.Tensor:
        """``H(pi)`` ``(*batch_shape)``, summed over ``x`` and ``phi``."""
        raise NotImplementedError

    def scale(self) -> torch.Tensor | None:
        """The spread parameter per stream ``(*batch_shape, 2)`` (``None``: it has none)."""
        return None

    def act(self, generator: torch.Generator | None, greedy: bool = False) -> torch.Tensor:
        """The pose to glance at: the mode when ``greedy`` and there is one, else a sample."""
        q = self.mode() if greedy else None
        return self.sample(generator) if q is None else q

    @classmethod
    def stack(cls, dists: list[LocationDistribution]) -> LocationDistribution:
        """One distribution of batch shape ``(len(dists), *batch_shape)`` (one per glance)."""
        raise NotImplementedError


class TruncatedGaussian(LocationDistribution):
    """``N(mu, sigma)`` per stream, sampled truncated to ``[-1, 1]``.

    ``log_prob`` and ``entropy`` are those of the untruncated Gaussian, as in the paper: the
    derivatives of ``log_prob`` are its eligibilities ``zeta_mu`` and ``zeta_sigma`` (Eqs
    reinforce_mean, reinforce_std; :func:`ham.model.location_net.gaussian_log_prob`).
    """

    trainable = True

    def __init__(
        self, mu: torch.Tensor, sigma: torch.Tensor, choice_log_prob: torch.Tensor | None = None
    ) -> None:
        self.mu = mu
        self.sigma = sigma
        #: ``(*batch_shape)`` the log-probability of a discrete choice made before the pose (the
        #: mixture component of :class:`FirstPose`), added to :meth:`log_prob`; ``None``: none
        self.choice_log_prob = choice_log_prob
        #: ``(*batch_shape)`` that choice (the component drawn), where one was made
        self.choice: torch.Tensor | None = None

    @property
    def batch_shape(self) -> torch.Size:
        return self.mu.shape[:-1]

    def sample(self, generator: torch.Generator | None) -> torch.Tensor:
        return truncated_normal(self.mu, self.sigma, generator)

    def log_prob(self, q: torch.Tensor) -> torch.Tensor:
        log_p = gaussian_log_prob(q, self.mu, self.sigma).sum(-1)
        return log_p if self.choice_log_prob is None else log_p + self.choice_log_prob

    def mode(self) -> torch.Tensor:
        # tanh keeps mu inside [-1, 1]; a diverged network's NaN becomes pose 0, as in sampling.
        return torch.nan_to_num(self.mu.detach()).clamp(-1, 1)

    def entropy(self) -> torch.Tensor:
        return (_HALF_LOG_2PI_E + torch.log(self.sigma)).sum(-1)

    def scale(self) -> torch.Tensor:
        return self.sigma.detach()

    @classmethod
    def stack(cls, dists: list[LocationDistribution]) -> TruncatedGaussian:
        mu, sigma = torch.stack([d.mu for d in dists]), torch.stack([d.sigma for d in dists])
        if all(d.choice_log_prob is None for d in dists):
            return cls(mu, sigma)
        choice = [
            d.mu.new_zeros(d.batch_shape) if d.choice_log_prob is None else d.choice_log_prob
            for d in dists
        ]
        return cls(mu, sigma, torch.stack(choice))


class Uniform(LocationDistribution):
    """Poses uniform in ``[-1, 1]^k``: density ``2^-k``, no parameters, no mode."""

    def __init__(
        self, batch_shape: tuple[int, ...], device: torch.device | str = "cpu", dims: int = 2
    ) -> None:
        self._shape = torch.Size(batch_shape)
        self.device = torch.device(device)
        self.dims = dims

    @property
    def batch_shape(self) -> torch.Size:
        return self._shape

    def sample(self, generator: torch.Generator | None) -> torch.Tensor:
        # for batch shape (B,) the same draw as uniform_locations (the first glance)
        return torch.rand(*self._shape, self.dims, generator=generator, device=self.device) * 2 - 1

    def log_prob(self, q: torch.Tensor) -> torch.Tensor:
        return torch.full(q.shape[:-1], -self.dims * math.log(2.0), dtype=q.dtype, device=q.device)

    def mode(self) -> None:
        return None

    def entropy(self) -> torch.Tensor:
        return torch.full(self._shape, self.dims * math.log(2.0), device=self.device)

    @classmethod
    def stack(cls, dists: list[LocationDistribution]) -> Uniform:
        first = dists[0]
        return cls((len(dists), *first.batch_shape), first.device, first.dims)


class LocationPolicy(nn.Module):
    """Base of the location policies: ``distribution(tau)`` from the core output ``tau``.

    Subclasses set ``name`` (through :func:`register_policy`) and build themselves from a
    :class:`ham.model.agent.HamConfig` in :meth:`from_config`.
    """

    name: ClassVar[str] = ""

    @classmethod
    def from_config(cls, config: Any) -> LocationPolicy:
        raise NotImplementedError

    def distribution(self, tau: torch.Tensor) -> LocationDistribution:
        raise NotImplementedError

    def distribution_at(
        self, tau: torch.Tensor, glance: int | None, position: torch.Tensor | None = None
    ) -> LocationDistribution:
        """The distribution of glance ``glance`` (0-based) from ``tau``, the sensor now at
        ``position`` ``(B, k)``; index and position are read only by policies that need them
        (``grid``, ``grid-corner``), the others return ``distribution(tau)``."""
        return self.distribution(tau)


#: name -> policy class; ``HamConfig.policy`` is one of its keys
POLICIES: dict[str, type[LocationPolicy]] = {}


@checked_arguments
def register_policy(name: str):
    """Class decorator: make a :class:`LocationPolicy` available as ``HamConfig(policy=name)``.
    Names are letters, digits and ``_ . -``; a name registered already is refused."""
    check_new_name("location policy", name, POLICIES)

    def add(cls: type[LocationPolicy]) -> type[LocationPolicy]:
        check_new_name("location policy", name, POLICIES)  # again: registered since
        cls.name = name
        POLICIES[name] = cls
        return cls

    return add


def make_policy(config: Any) -> LocationPolicy:
    """The policy ``config.policy`` names, built from ``config`` (a HamConfig)."""
    try:
        cls = POLICIES[config.policy]
    except KeyError:
        raise HamError(f"policy = {config.policy!r}; accepted: {', '.join(POLICIES)}") from None
    return cls.from_config(config)


@register_policy("learned")
class GaussianPolicy(LocationNetwork, LocationPolicy):
    """The paper's location network: ``tau -> (mu, sigma)``, a truncated Gaussian per stream.

    The weights are those of :class:`ham.model.location_net.LocationNetwork` (heads ``mu`` and
    ``sigma``), so checkpoints are unchanged.
    """

    @classmethod
    def from_config(cls, config: Any) -> GaussianPolicy:
        return cls(
            config.hidden_units,
            config.std_activation,
            config.sigma_min,
            config.bias,
            dims=len(config.pose_dims),
            trains_input=config.encoders == "separate",
        )

    def distribution(self, tau: torch.Tensor) -> TruncatedGaussian:
        mu, sigma = self(tau)
        return TruncatedGaussian(mu, sigma)


class FirstPose(nn.Module):
    """The first glance's own pose distribution (``HamConfig.first_glance = "own"``, beyond the
    paper), the same for every episode (there is nothing to condition on before the first
    glance): a mixture of ``M`` Gaussians over the pose space, component ``m`` with weight
    ``softmax(w)_m``, mean ``tanh(a_m)`` and ``sigma_m = exp(l_m) + sigma_min`` per pose
    dimension. A first pose is drawn in two steps, a component ``c ~ softmax(w)`` and the pose
    ``q ~ N(tanh(a_c), sigma_c)`` truncated to ``[-1, 1]``; the policy gradient trains the
    joint action, ``log pi(c, q) = log softmax(w)_c + log N(q; tanh(a_c), sigma_c)``, with the
    later glances' (:attr:`TruncatedGaussian.choice_log_prob`). Greedy: the mean of the heaviest
    component.

    Why parameters of its own: the ``learned`` first glance is the location network at a zero
    core output, its biases alone, which every later glance's gradient pulls too, at the
    location network's small, decaying learning rate; under Adam a weight moves at most about
    its learning rate a step, so sigma could not shrink onto the few poses that tell all objects
    apart (docs/learners.md). Here they learn at their own rate
    (``TrainConfig.first_pose_lr_scale``); ``log sigma``: an Adam step changes sigma by a factor.
    Why a mixture is offered: the expected information of one glance is flat over wide regions
    of poses that tell 3 of 4 objects apart, next to narrow bands that tell all 4; one Gaussian
    climbs into the plateau nearest to where it started and narrows there. ``grid`` components
    per pose dimension (``M = grid^k``) start at the centres of a regular grid over ``[-1,
    1]^k`` with sigma ``1 / grid`` (half their spacing), each climbs locally, and the weights
    choose among them. Measured on the paper's table it ends on a 3-of-4 plateau as the single
    Gaussian does (docs/learners.md), so the default is ``grid = 1``: one Gaussian at pose 0
    with sigma 1.
    """

    def __init__(self, dims: int = 2, grid: int = 1, sigma_min: float = 1e-3) -> None:
        super().__init__()
        if not sigma_min >= 0:
            raise HamError(f"sigma_min = {sigma_min!r}; accepted: >= 0")
        if not (isinstance(grid, int) and not isinstance(grid, bool) and grid >= 1):
            raise HamError(f"first pose grid = {grid!r}; accepted: an integer >= 1")
        self.sigma_min = sigma_min
        centres = (2 * torch.arange(grid, dtype=torch.float64) + 1) / grid - 1
        mesh = torch.cartesian_prod(*[centres] * dims).reshape(-1, dims)
        self.mean = nn.Parameter(torch.atanh(mesh).float())  # (M, k): tanh(a) = the centres
        self.log_sigma = nn.Parameter(torch.full_like(self.mean, -math.log(grid)))
        self.weight = nn.Parameter(torch.zeros(mesh.shape[0]))  # (M,) logits, uniform

    @property
    def components(self) -> int:
        return self.weight.shape[0]

    def distribution(
        self,
        batch: int,
        generator: torch.Generator | None = None,
        greedy: bool = False,
        choice: torch.Tensor | None = None,
    ) -> TruncatedGaussian:
        """The first poses' distribution for ``batch`` episodes ``(batch,)``: each episode's
        component drawn from ``generator`` (greedy: the heaviest; or ``choice`` ``(batch,)``,
        the components an episode played), a Gaussian at it. The components drawn are
        :attr:`TruncatedGaussian.choice`."""
        log_w = torch.log_softmax(self.weight, -1)
        if choice is not None:
            c = choice
        elif greedy:
            c = log_w.detach().argmax().expand(batch)
        elif self.components == 1:  # no draw: one component
            c = torch.zeros(batch, dtype=torch.long, device=log_w.device)
        else:
            c = torch.multinomial(
                log_w.detach().exp(), batch, replacement=True, generator=generator
            )
        mu = torch.tanh(self.mean)[c]
        sigma = self.log_sigma.exp()[c] + self.sigma_min
        dist = TruncatedGaussian(mu, sigma, log_w[c] if self.components > 1 else None)
        dist.choice = c
        return dist


class ProbedFirstPose(nn.Module):
    """The first glance's pose found by a global search (``HamConfig.first_glance = "probe"``,
    beyond the paper): the state of the search over a lattice of candidate first poses, and the
    first poses it gives. The search itself (probe glances, successive halving) is
    :mod:`ham.learn.probe`; this holds what a checkpoint must keep.

    Two phases: searching (warm-up included): a pose drawn uniformly among the surviving
    candidates, at first all of them (training teaches the classifier every candidate, then
    keeps teaching it the ones still in the race); committed: the winner, for every episode
    (greedy or not). Why lattice poses from the start and not uniform ones: the bands that tell
    all objects apart are narrow (on the paper's table the one at ``q_phi = 0`` is one grid
    point wide), a classifier trained on uniform poses has hardly seen them, and the search
    would drop them in its first round for a score of the unknown (measured, docs/learners.md).

    Why a search beside the policy gradient (``own``): the expected information of one glance
    is flat over wide plateaus of poses that tell 3 of 4 objects apart and peaks in narrow bands
    that tell all 4; a Gaussian climbs the nearest plateau and never sees a band 0.1-0.2 away
    (docs/learners.md). A lattice sees every band at least one candidate wide.

    Buffers: ``candidates`` ``(N, k)`` (``grid`` points per pose dimension from -1 to 1,
    rebuilt, not saved), ``alive`` ``(N,)``, ``committed``, ``pose`` ``(k,)``, ``probes``
    (probe glances spent, environment steps). Draws no random numbers when built.
    """

    def __init__(self, dims: int = 2, grid: int = 21) -> None:
        super().__init__()
        if not (isinstance(grid, int) and not isinstance(grid, bool) and grid >= 2):
            raise HamError(f"probe grid = {grid!r}; accepted: an integer >= 2")
        axis = torch.linspace(-1.0, 1.0, grid, dtype=torch.float64)
        mesh = torch.cartesian_prod(*[axis] * dims).reshape(-1, dims).float()
        self.register_buffer("candidates", mesh, persistent=False)
        self.register_buffer("alive", torch.ones(mesh.shape[0], dtype=torch.bool))
        self.register_buffer("committed", torch.tensor(False))
        self.register_buffer("pose", torch.zeros(dims))
        self.register_buffer("probes", torch.tensor(0, dtype=torch.long))

    @property
    def dims(self) -> int:
        return self.candidates.shape[1]

    def first_poses(
        self, batch: int, generator: torch.Generator | None, device: torch.device | str = "cpu"
    ) -> torch.Tensor:
        """``(batch, k)`` first poses for the phase the search is in (see the class)."""
        if bool(self.committed):
            return self.pose.to(device).expand(batch, -1).clone()
        idx = self.alive.nonzero()[:, 0]
        pick = torch.randint(len(idx), (batch,), generator=generator, device=idx.device)
        return self.candidates[idx[pick]].to(device)


@register_policy("random")
class UniformPolicy(LocationPolicy):
    """Random locations (the paper's ``pi_rloc``): uniform poses, whatever the core says."""

    def __init__(self, dims: int = 2) -> None:
        super().__init__()
        self.dims = dims

    @classmethod
    def from_config(cls, config: Any) -> UniformPolicy:
        return cls(len(config.pose_dims))

    def distribution(self, tau: torch.Tensor) -> Uniform:
        return Uniform((tau.shape[0],), tau.device, self.dims)


class SquashedGaussian(LocationDistribution):
    """``q = tanh(u)``, ``u ~ N(m, s)`` per stream: the squashed Gaussian of soft actor-critic.

    Why beside the truncated Gaussian: a reparametrized sample of a Gaussian *truncated* to
    ``[-1, 1]`` stops depending on ``mu`` and ``sigma`` as ``sigma`` grows (it tends to the
    uniform draw), so an actor trained through its samples (``--learner sac``) loses its
    gradient once its spread is wide; ``tanh(m + s eps)`` always moves with ``m``.
    ``log_prob`` is the exact density of ``q`` (the Gaussian's at ``atanh q`` less
    ``log(1 - q^2)``); ``mode`` is ``tanh(m)`` (SAC's deterministic action); ``entropy`` is the
    Gaussian's less ``log(1 - tanh(m)^2)`` at the mode (an approximation: the exact one has no
    closed form).
    """

    trainable = True
    #: ``|q|`` at most ``1 - EDGE`` where ``atanh`` is taken (float32 resolution near 1)
    EDGE = 1e-6

    def __init__(self, m: torch.Tensor, s: torch.Tensor) -> None:
        self.m = m
        self.s = s

    @property
    def batch_shape(self) -> torch.Size:
        return self.m.shape[:-1]

    @staticmethod
    def _log_det(u: torch.Tensor) -> torch.Tensor:
        """``log(1 - tanh(u)^2)``, stable for large ``|u|``."""
        return 2 * (math.log(2.0) - u - torch.nn.functional.softplus(-2 * u))

    def _log_prob_u(self, u: torch.Tensor) -> torch.Tensor:
        return (gaussian_log_prob(u, self.m, self.s) - self._log_det(u)).sum(-1)

    def rsample(self, generator: torch.Generator | None) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparametrized sample ``q`` (differentiable in ``m`` and ``s``) and ``log pi(q)``."""
        eps = torch.randn(self.m.shape, generator=generator, device=self.m.device)
        u = self.m + self.s * eps.to(self.m.dtype)
        return torch.tanh(u), self._log_prob_u(u)

    def sample(self, generator: torch.Generator | None) -> torch.Tensor:
        with torch.no_grad():
            q, _ = self.rsample(generator)
        # a diverged network's NaN becomes pose 0 (the loss shows the NaN), as in the truncated one
        return torch.nan_to_num(q, nan=0.0)

    def log_prob(self, q: torch.Tensor) -> torch.Tensor:
        edge = 1 - self.EDGE
        return self._log_prob_u(torch.atanh(q.clamp(-edge, edge)))

    def mode(self) -> torch.Tensor:
        return torch.nan_to_num(torch.tanh(self.m.detach()))

    def entropy(self) -> torch.Tensor:
        return (_HALF_LOG_2PI_E + torch.log(self.s) - self._log_det(self.m)).sum(-1)

    def scale(self) -> torch.Tensor:
        return self.s.detach()

    @classmethod
    def stack(cls, dists: list[LocationDistribution]) -> SquashedGaussian:
        return cls(torch.stack([d.m for d in dists]), torch.stack([d.s for d in dists]))


@register_policy("squashed")
class SquashedGaussianPolicy(GaussianPolicy):
    """The location network's weights (heads ``mu`` and ``sigma``, as ``learned``) as a squashed
    Gaussian: ``q = tanh(u)``, ``u ~ N(m, s)`` with ``m`` the ``mu`` head's output before its
    ``tanh`` and ``s`` the ``sigma`` head's spread (:class:`SquashedGaussian`); its mode is
    ``learned``'s mean pose ``tanh(m)``. Beyond the paper: the policy of ``--learner sac``."""

    def distribution(self, tau: torch.Tensor) -> SquashedGaussian:
        tau = tau.detach()  # the core is not trained through the location branch
        s = self.sigma(tau)
        s = F.softplus(s) if self.std_activation == "softplus" else torch.sigmoid(s)
        return SquashedGaussian(self.mu(tau), s + self.sigma_min)


def raster_counts(glances: int, dims: int = 2) -> list[int]:
    """Cells per axis of the smallest near-square raster with at least ``glances`` cells over
    ``dims`` axes (first axis first): each axis, from the last, takes the ceiling of the
    remaining cells' root (16 glances in 2-D: ``[4, 4]``; 10: ``[4, 3]``)."""
    counts, left = [], glances
    for axis in range(dims, 0, -1):
        n = max(1, math.ceil(left ** (1.0 / axis) - 1e-9))
        counts.append(n)
        left = math.ceil(left / n)
    return counts


def sweep(glances: int, dims: int = 2) -> np.ndarray:
    """The grid sweep's poses: ``G`` cell centres of the raster :func:`raster_counts` over
    ``[-1, 1]^dims``, the first axis fastest (``(G, dims)``; on the paper's table ``(q_x,
    q_phi)``, row by row). The table baseline ``grid`` (:mod:`ham.learn.planners`) and the
    ``grid`` policy's absolute poses."""
    counts = raster_counts(glances, dims)
    axes = [-1 + (2 * np.arange(n) + 1) / n for n in reversed(counts)]
    cells = itertools.product(*axes)  # the last axis slowest, the first fastest
    return np.array([tuple(reversed(c)) for c in cells][:glances])


def snake(glances: int, dims: int = 2) -> np.ndarray:
    """``G`` integer lattice points ``(G, dims)`` of the raster :func:`raster_counts` in
    boustrophedon order: the first axis fastest, each axis' direction reversed whenever the
    (reversed) coordinates above it sum to an odd number (a reflected Gray code), so
    consecutive points differ by one unit along one axis."""
    counts = raster_counts(glances, dims)
    points = []
    for cell in itertools.product(*[range(n) for n in reversed(counts)]):
        raw = list(reversed(cell))  # first axis first
        out = [0] * dims
        above = 0
        for j in range(dims - 1, -1, -1):
            out[j] = counts[j] - 1 - raw[j] if above % 2 else raw[j]
            above += out[j]
        points.append(out)
    return np.array(points[:glances], dtype=np.int64).reshape(-1, dims)


class FixedPose(LocationDistribution):
    """One pose per episode, no randomness: a point mass (``log_prob`` 0, entropy 0); its mode
    is the pose. No parameters: no REINFORCE term."""

    def __init__(self, pose: torch.Tensor) -> None:
        self.pose = pose

    @property
    def batch_shape(self) -> torch.Size:
        return self.pose.shape[:-1]

    def sample(self, generator: torch.Generator | None) -> torch.Tensor:
        return self.pose.clone()  # draws nothing from the generator

    def log_prob(self, q: torch.Tensor) -> torch.Tensor:
        return q.new_zeros(q.shape[:-1])

    def mode(self) -> torch.Tensor:
        return self.pose.clone()

    def entropy(self) -> torch.Tensor:
        return self.pose.new_zeros(self.batch_shape)

    @classmethod
    def stack(cls, dists: list[LocationDistribution]) -> FixedPose:
        return cls(torch.stack([d.pose for d in dists]))


@register_policy("grid")
class GridPolicy(LocationPolicy):
    """A fixed systematic sweep (beyond the paper): the same pose at glance ``s`` of every
    episode, whatever the core says; no weights, no REINFORCE term; its mode is the sweep's pose.

    * Absolute poses (the haptic world, ap_gym's ``absolute`` actions): the ``n`` glances the
      policy chooses visit the raster of :func:`sweep` over ``[-1, 1]^k`` in its order (the
      table baseline ``grid``'s poses), ``n = S`` when it chooses the first glance
      (``first_glance = "learned"``: then exactly the table baseline's ``G = S`` poses), else
      ``S - 1`` (glance 1 random).
    * Moves (``HamConfig.moves``, ap_gym's ``relative`` actions): the sensor starts where the
      environment puts it and walks the boustrophedon :func:`snake` of the ``S`` glances: each
      move the largest step along one axis (action ``+-1`` on it: ``max_step_length``, 0.2 on
      CircleSquare), along the first axis (``x``) and one step along the second at each row's
      end; 16 glances: 4 rows of 4 glimpses, 0.2 apart, a square of 0.6 x 0.6 (the image is
      2 x 2). Open loop: it does not know where it starts, and a move past the border is
      clipped by the environment. (The first glance's move, chosen with ``first_glance =
      "learned"``, is zero: the environment gives the first glimpse before any move.)
    """

    def __init__(
        self, glances: int, dims: int = 2, moves: bool = False, first_chosen: bool = False
    ) -> None:
        super().__init__()
        self.dims = dims
        if moves:
            points = torch.from_numpy(snake(glances, dims)).double()
            poses = torch.cat([points.new_zeros(1, dims), points.diff(dim=0)])
        else:
            skip = 0 if first_chosen else 1  # glance 1 random: the sweep covers the rest
            chosen = torch.from_numpy(sweep(glances - skip, dims)).reshape(-1, dims)
            poses = torch.cat([chosen.new_zeros(skip, dims), chosen])
        #: ``(S, k)`` the pose (or move) of each glance; row 0 unused when glance 1 is random
        self.register_buffer("poses", poses.float(), persistent=False)

    @classmethod
    def from_config(cls, config: Any) -> GridPolicy:
        return cls(
            config.glances,
            len(config.pose_dims),
            config.moves,
            config.first_glance == "learned",
        )

    def distribution(self, tau: torch.Tensor) -> FixedPose:
        raise HamError(
            "the grid policy needs the glance index; accepted: distribution_at(tau, glance) "
            "(the model's rollout; not --learner sac)"
        )

    def distribution_at(
        self, tau: torch.Tensor, glance: int | None, position: torch.Tensor | None = None
    ) -> FixedPose:
        if glance is None or not 0 <= glance < self.poses.shape[0]:
            raise HamError(
                f"grid policy asked for glance {glance!r}; accepted: 0 .. {self.poses.shape[0] - 1}"
            )
        pose = self.poses[glance].to(device=tau.device, dtype=tau.dtype)
        return FixedPose(pose.expand(tau.shape[0], self.dims))


@register_policy("grid-corner")
class CornerGridPolicy(LocationPolicy):
    """APPLE's grid in our words (beyond the paper; ap_gym's ``relative`` actions only): closed
    loop on where the glimpse is. At glance 2 (the first move) it plans from the start ``p_0``:
    the nearest image corner ``c = (s_x, s_y)``, ``s = sign(p_0)`` (``+1`` at 0), then columns
    ``x = s_x (1 - 0.5 j)``, ``j = 0 .. 4``, alternately to ``-s_y`` and back to ``s_y``; each
    step goes ``move_length`` (the environment's full step) toward the next waypoint, ending a
    step at a waypoint it reaches. Each move is ``(plan_s - position) / move_length``, from
    where the glimpse is now (the where-input), so the walk follows the plan exactly. The plan
    is the policy's only state, made anew from each episode's start; no weights, no REINFORCE
    term; its mode is the move (the evaluation's mean poses)."""

    #: spacing of the columns over the ``[-1, 1]`` image, as APPLE's grid (5 columns)
    COLUMN_SPACING = 0.5

    def __init__(self, glances: int, move_length: float) -> None:
        super().__init__()
        self.glances = glances
        self.move_length = move_length
        self.plan: torch.Tensor | None = None  # (S, B, 2) positions of glances 1..S

    @classmethod
    def from_config(cls, config: Any) -> CornerGridPolicy:
        if not config.moves or len(config.pose_dims) != 2 or config.move_length <= 0:
            raise HamError(
                f"policy 'grid-corner' on a world of moves = {config.moves}, "
                f"{len(config.pose_dims)} pose dims; accepted: an ap_gym image environment "
                "with --actions relative (moves of a glimpse over a 2-d image)"
            )
        if config.first_glance != "random":
            raise HamError(
                f"first_glance = {config.first_glance!r} with policy 'grid-corner'; accepted: "
                "random (the environment's first glimpse, where the walk starts)"
            )
        return cls(config.glances, config.move_length)

    @classmethod
    def waypoints(cls, start: torch.Tensor) -> torch.Tensor:
        """``(W, B, 2)``: the nearest corner of each start ``(B, 2)``, then the columns' ends."""
        sign = torch.where(start >= 0, 1.0, -1.0).to(start.dtype)
        columns = round(2 / cls.COLUMN_SPACING) + 1
        points = []
        for j in range(columns):
            x = sign[:, 0] * (1 - cls.COLUMN_SPACING * j)
            ends = (sign[:, 1], -sign[:, 1]) if j % 2 == 0 else (-sign[:, 1], sign[:, 1])
            points += [torch.stack([x, y], -1) for y in ends]
        return torch.stack(points)

    def make_plan(self, start: torch.Tensor) -> torch.Tensor:
        """``(S, B, 2)``: the glimpse's positions of glances 1..S from ``start`` ``(B, 2)``."""
        targets = self.waypoints(start)
        index = torch.zeros(start.shape[0], dtype=torch.long, device=start.device)
        last = targets.shape[0] - 1
        rows, p = [start], start
        for _ in range(self.glances - 1):
            target = targets[index, torch.arange(start.shape[0], device=start.device)]
            gap = target - p
            dist = gap.norm(dim=-1, keepdim=True)
            # a full step toward the waypoint, or onto it when it is nearer
            p = torch.where(dist <= self.move_length, target, p + gap / dist * self.move_length)
            reached = (dist <= self.move_length).squeeze(-1)
            index = torch.where(reached, (index + 1).clamp(max=last), index)
            rows.append(p)
        return torch.stack(rows)

    def distribution(self, tau: torch.Tensor) -> FixedPose:
        raise HamError(
            "the grid-corner policy needs the glance index and the glimpse's position; "
            "accepted: distribution_at(tau, glance, position) (the model's rollout; not "
            "--learner sac)"
        )

    def distribution_at(
        self, tau: torch.Tensor, glance: int | None, position: torch.Tensor | None = None
    ) -> FixedPose:
        if glance is None or not 1 <= glance < self.glances or position is None:
            raise HamError(
                f"grid-corner policy asked for glance {glance!r} at position "
                f"{'none' if position is None else 'given'}; accepted: glances 1 .. "
                f"{self.glances - 1} with the glimpse's position"
            )
        position = position.to(device=tau.device, dtype=torch.float64)
        if glance == 1:  # a new episode: plan from its start
            self.plan = self.make_plan(position)
        elif self.plan is None or self.plan.shape[1] != position.shape[0]:
            raise HamError(
                f"grid-corner policy asked for glance {glance} before glance 1 of the episode; "
                "accepted: the glances of an episode in order"
            )
        move = (self.plan[glance] - position) / self.move_length
        return FixedPose(move.to(tau.dtype))
