"""Pure maths of DDPG: TD target, the critic's loss, the actor's inverting-gradients
surrogate, target-network updates, FedProx's pull, discounted returns, and the quantile
critic's loss and CVaR."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor


def td_target(rewards: Tensor, terminated: Tensor, next_q: Tensor, gamma: float | Tensor) -> Tensor:
    """Target ``r + gamma * (1 - terminated) * Q'(s', mu'(s'))``.

    Only true terminations cut the bootstrap; a time-limit truncation must arrive here
    with ``terminated = 0``. For n-step transitions ``r`` is the discounted reward sum and
    ``gamma`` a tensor of ``gamma**k``, k the steps each one spans.
    """
    return rewards + gamma * (1.0 - terminated) * next_q


def critic_loss(
    q: Tensor, rewards: Tensor, terminated: Tensor, next_q: Tensor, discount: float | Tensor,
    quantile: bool,
) -> tuple[Tensor, Tensor]:  # fmt: skip
    """The reward critic's loss and its batch's mean |TD error|: the squared error to the
    n-step TD target (DDPG), or for a quantile critic (``quantile``, q and next_q of
    shape (batch, quantiles)) the quantile Huber loss to the target's quantiles, its TD
    error taken between the quantiles' means."""
    if quantile:
        per_sample = discount.unsqueeze(-1) if isinstance(discount, Tensor) else discount
        target = td_target(rewards.unsqueeze(-1), terminated.unsqueeze(-1), next_q, per_sample)
        error = (q.detach().mean(-1) - target.mean(-1)).abs().mean()
        return quantile_huber_loss(q, target), error
    target = td_target(rewards, terminated, next_q, discount)
    return F.mse_loss(q, target), (q.detach() - target).abs().mean()


@torch.no_grad()
def soft_update(targets: Sequence[Tensor], sources: Sequence[Tensor], tau: float) -> None:
    """Polyak averaging in place: ``target <- (1 - tau) * target + tau * source``.

    One fused ``_foreach_lerp_`` over all tensors (``lerp(t, s, tau) = t + tau * (s - t)``)
    instead of a Python loop of small kernels.
    """
    if len(targets) != len(sources):
        raise ValueError(f"{len(targets)} targets but {len(sources)} sources")
    torch._foreach_lerp_(list(targets), list(sources), tau)


@torch.no_grad()
def hard_update(targets: Sequence[Tensor], sources: Sequence[Tensor]) -> None:
    """Copy ``sources`` into ``targets`` in place."""
    if len(targets) != len(sources):
        raise ValueError(f"{len(targets)} targets but {len(sources)} sources")
    torch._foreach_copy_(list(targets), list(sources))


def inverting_gradients_loss(preactivation: Tensor, dq_da: Tensor) -> Tensor:
    """A surrogate whose gradient in ``preactivation`` (the actor's unbounded action ``p``)
    is DDPG's by inverting gradients (Hausknecht and Stone 2016).

    ``dq_da``, the critic's gradient at the clipped action, is scaled by ``(1 - p) / 2``
    where it asks for more and ``(p + 1) / 2`` where it asks for less: it fades as the
    output nears the bound it points to and turns round beyond it, so the output stays
    within [-1, 1] and can always come back.
    """
    room = preactivation.detach()
    scale = torch.where(dq_da > 0, (1.0 - room) / 2.0, (room + 1.0) / 2.0)
    return -(dq_da * scale * preactivation).sum() / preactivation.shape[0]


def quantile_midpoints(count: int, device: torch.device | str = "cpu") -> Tensor:
    """The quantile levels a quantile critic's outputs stand for: (2i + 1) / (2 count),
    made on ``device`` (a captured update copies nothing from the host)."""
    return (torch.arange(count, dtype=torch.float32, device=device) + 0.5) / count


def quantile_huber_loss(quantiles: Tensor, targets: Tensor, kappa: float = 1.0) -> Tensor:
    """QR-DQN's loss (Dabney et al. 2018): ``quantiles`` (batch, N) of Z(s, a) regressed
    on every sample of ``targets`` (batch, M) of r + gamma Z'(s', a').

    Each pair (i, j) has ``u = target_j - quantile_i`` and weight ``|tau_i - 1{u < 0}|``
    on the Huber loss of u (threshold ``kappa``) divided by kappa; summed over i, averaged
    over j and the batch. Quantile i then settles where a share tau_i of targets lies below.
    """
    if quantiles.dim() != 2 or targets.dim() != 2 or quantiles.shape[0] != targets.shape[0]:
        raise ValueError(
            f"expected (batch, N) quantiles and (batch, M) targets, got "
            f"{tuple(quantiles.shape)} and {tuple(targets.shape)}"
        )
    taus = quantile_midpoints(quantiles.shape[1], quantiles.device)
    u = targets.unsqueeze(1) - quantiles.unsqueeze(2)  # (batch, N, M)
    absolute = u.abs()
    huber = torch.where(absolute <= kappa, 0.5 * u.square(), kappa * (absolute - 0.5 * kappa))
    weight = (taus.view(1, -1, 1) - (u.detach() < 0).float()).abs()
    return (weight * huber / kappa).sum(dim=1).mean()


def lower_tail_mean(quantiles: Tensor, alpha: float) -> Tensor:
    """CVaR at level ``alpha`` of a return given by equally weighted ``quantiles`` (batch, N):
    the mean of its worst ceil(alpha N) quantiles (all of them at alpha = 1: the mean)."""
    if not 0 < alpha <= 1:
        raise ValueError(f"alpha must lie in (0, 1], got {alpha!r}")
    count = quantiles.shape[-1]
    worst = max(1, math.ceil(alpha * count - 1e-9))
    if worst == count:
        return quantiles.mean(dim=-1)
    return torch.sort(quantiles, dim=-1).values[..., :worst].mean(dim=-1)


class ProximalPull:
    """FedProx (Li et al. 2020): the gradient of mu/2 ||w - w_anchor||^2, mu (w - w_anchor),
    added to each anchored parameter's gradient before its optimizer steps."""

    def __init__(self) -> None:
        self.mu = 0.0
        self.anchors: dict[object, list[tuple[Tensor, Tensor]]] = {}
        """Per optimizer: (parameter, the value it is pulled towards)."""

    def anchor(self, mu: float, networks: dict[object, torch.nn.Module]) -> None:
        """Pull each optimizer's network towards its parameters as they are now; mu = 0:
        no pull. Anchoring the same networks again at the same mu (FedProx, every round)
        copies into the anchors in place: an update captured as a CUDA graph, which reads
        them where they lie, replays on without a new capture."""
        if not mu >= 0:
            raise ValueError(f"proximal mu must be >= 0, got {mu!r}")
        pairs = {optimizer: list(net.parameters()) for optimizer, net in networks.items()}
        if float(mu) == self.mu and mu > 0 and self._anchors_params(pairs):
            anchors = [anchor for held in self.anchors.values() for _, anchor in held]
            params = [p.detach() for held in pairs.values() for p in held]
            with torch.no_grad():
                torch._foreach_copy_(anchors, params)
            return
        self.mu = float(mu)
        self.anchors = {
            optimizer: [(p, p.detach().clone()) for p in params] if mu else []
            for optimizer, params in pairs.items()
        }

    def _anchors_params(self, pairs: dict[object, list[Tensor]]) -> bool:
        """Whether the anchors are held for exactly these parameters."""
        if self.anchors.keys() != pairs.keys():
            return False
        held = {optimizer: [param for param, _ in self.anchors[optimizer]] for optimizer in pairs}
        return all(
            len(held[optimizer]) == len(params)
            and all(a is b for a, b in zip(held[optimizer], params, strict=True))
            for optimizer, params in pairs.items()
        )

    @torch.no_grad()
    def add_gradient(self, optimizer: object) -> None:
        for param, anchor in self.anchors.get(optimizer, ()):
            pull = (param - anchor).mul_(self.mu)
            if param.grad is None:
                param.grad = pull
            else:
                param.grad.add_(pull)


def discounted_returns(rewards: Sequence[float], gamma: float) -> np.ndarray:
    """Return-to-go ``G_t = r_t + gamma * G_{t+1}`` of every step of an episode (float64).

    What a critic's Q(s_t, a_t) estimates for a policy that took these actions, when the
    episode ended by termination (a truncated episode's tail is missing).
    """
    returns = np.empty(len(rewards), np.float64)
    running = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        running = float(rewards[t]) + gamma * running
        returns[t] = running
    return returns
