"""The location network: a stochastic policy for the pose of the next glance.

Section "The Location Network": from the core's output ``tau_{1:s}`` two Gaussian streams, one for
the position ``q_x`` and one for the orientation ``q_phi``, each with its own mean (``tanh``, so
``mu in [-1, 1]``) and standard deviation (``softplus`` in the paper; ``sigmoid`` in the authors'
code). Column 0 of each head is the ``x`` stream, column 1 the ``phi`` stream; two 256 -> 2 heads
hold exactly the weights of the authors' four 256 -> 1 heads.

A sample outside ``[-1, 1]`` is "resampled" (the paper): we draw from the Gaussian truncated to
``[-1, 1]`` directly by inverse-CDF sampling, which is the same distribution, vectorized, with no
loop. The pose is then ``l = (q_x, q_phi * pi/2) = (x, phi)``.

What is detached (paper; the authors' code, docs/sources.md "The network": the core is not
trained through the location branch):

* the core output enters the location network detached: the REINFORCE term trains only the
  location heads, never the core or the tactile network (with an encoder of its own,
  ``HamConfig.encoders = "separate"``, beyond the paper, it trains that encoder too:
  ``trains_input``);
* the sample ``q`` is drawn from detached ``mu, sigma`` and carries no gradient: the eligibilities
  of Eqs (reinforce_mean, reinforce_std) differentiate ``log N(q; mu, sigma)`` at a *fixed* ``q``.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from ham.errors import HamError

STD_ACTIVATIONS: tuple[str, ...] = ("softplus", "sigmoid")


class LocationNetwork(nn.Module):
    """``tau -> (mu, sigma)``, each ``(B, k)``: one stream per pose dimension (``x`` and ``phi``
    in the paper, ``k = 2``; the paper's Discussion: one location stream per pose dimension).

    Args:
        input_size: width of the core output (256).
        dims: pose dimensions ``k``, one Gaussian stream each (2).
        std_activation: ``softplus`` (paper) or ``sigmoid`` (authors' code).
        sigma_min: a floor added to ``sigma`` (not in the paper) so that the eligibilities'
            ``1 / sigma^3`` stay finite.
        bias: give the heads a bias (the authors' code has none).
        trains_input: the gradient flows into ``tau`` (an encoder of the policy's own);
            ``False`` (the paper): ``tau`` is detached.
    """

    def __init__(
        self,
        input_size: int = 256,
        std_activation: str = "softplus",
        sigma_min: float = 1e-3,
        bias: bool = True,
        dims: int = 2,
        trains_input: bool = False,
    ) -> None:
        super().__init__()
        self.trains_input = trains_input
        if std_activation not in STD_ACTIVATIONS:
            raise HamError(
                f"std activation {std_activation!r}; accepted: {', '.join(STD_ACTIVATIONS)}"
            )
        if not sigma_min >= 0:
            raise HamError(f"sigma_min = {sigma_min!r}; accepted: >= 0")
        self.std_activation = std_activation
        self.sigma_min = sigma_min
        self.mu = nn.Linear(input_size, dims, bias=bias)
        self.sigma = nn.Linear(input_size, dims, bias=bias)

    def forward(self, tau: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if not self.trains_input:
            tau = tau.detach()  # the core is not trained through the location branch
        mu = torch.tanh(self.mu(tau))
        s = self.sigma(tau)
        sigma = F.softplus(s) if self.std_activation == "softplus" else torch.sigmoid(s)
        return mu, sigma + self.sigma_min


def truncated_normal(
    mu: torch.Tensor,
    sigma: torch.Tensor,
    generator: torch.Generator | None = None,
    low: float = -1.0,
    high: float = 1.0,
    uniform: torch.Tensor | None = None,
) -> torch.Tensor:
    """A sample of ``N(mu, sigma)`` truncated to ``[low, high]``, by inverse CDF, detached.

    ``u ~ U(Phi(a), Phi(b))`` with ``a, b = (low - mu)/sigma, (high - mu)/sigma``, then
    ``q = mu + sigma * Phi^-1(u)``: equal in distribution to resampling until the draw falls
    inside, in one vectorized step. Computed in float64; the result is clamped to ``[low, high]``
    against rounding, so it is always a valid action (never NaN). ``uniform``: the ``U[0, 1)``
    draws (float64, ``mu``'s shape) instead of drawing them from ``generator`` (batched runs
    draw each run's from its own generator and transform all at once).
    """
    m, s = mu.detach().double(), sigma.detach().double()
    a = torch.special.ndtr((low - m) / s)
    b = torch.special.ndtr((high - m) / s)
    u = uniform
    if u is None:
        u = torch.rand(m.shape, generator=generator, dtype=torch.float64, device=m.device)
    q = m + s * torch.special.ndtri(a + u * (b - a))
    q = torch.where(torch.isnan(q), m, q)  # sigma == 0: the mean itself
    # NaN parameters (a diverged network) give pose 0, so the glance still runs; the NaN shows in
    # the loss, where training stops with the step named.
    q = torch.nan_to_num(q, nan=0.0).clamp(low, high)
    return q.to(mu.dtype)


def uniform_locations(
    batch: int,
    generator: torch.Generator | None,
    device: torch.device | str = "cpu",
    dims: int = 2,
    uniform: torch.Tensor | None = None,
) -> torch.Tensor:
    """Uniform poses ``q ~ U[-1, 1]^k``, shape (B, k) (k = 2 in the paper): the first glance, and
    the random policy. ``uniform``: the ``U[0, 1)`` draws (any leading shape) instead of drawing
    them from ``generator`` (batched runs draw each run's from its own generator and transform
    all at once)."""
    if uniform is None:
        uniform = torch.rand(batch, dims, generator=generator, device=device)
    return uniform * 2 - 1


def gaussian_log_prob(q: torch.Tensor, mu: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """``log N(q; mu, sigma)`` elementwise (the untruncated density, as in the paper).

    Its derivatives are the characteristic eligibilities
    ``zeta_mu = (q - mu) / sigma^2`` (Eq reinforce_mean) and
    ``zeta_sigma = ((q - mu)^2 - sigma^2) / sigma^3`` (Eq reinforce_std).
    """
    return -torch.log(sigma) - 0.5 * ((q - mu) / sigma) ** 2 - 0.9189385332046727
