"""A critic of bootstrapped heads, and the price on their disagreement the actor pays.

The reward critic's last layer gives ``heads`` values per sample instead of one. Each
head learns from its own half of the replay buffer (a fixed Bernoulli(1/2) draw per
buffer slot and head, as Bootstrapped DQN's masks: Osband et al. 2016) towards its own
target head, so where the data say little, as near the rare collisions, the heads
disagree. The actor climbs their mean minus ``price`` times their spread: it is pushed
away from actions whose value the critic does not know (Hoel et al. 2020, arXiv
2006.09786, acted safely where an ensemble of critics disagreed at intersections).
The heads share the critic's trunk, so K heads cost K small output layers, not K critics.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from frl.agents.functional import td_target


def bootstrap_masks(seed_sequence: np.random.SeedSequence, slots: int, heads: int) -> Tensor:
    """Which heads learn from each buffer slot: (slots, heads) booleans, each True with
    probability 1/2, drawn once from ``seed_sequence``. A slot keeps its draw when the
    buffer overwrites it, so the masks need no place in a checkpoint."""
    rng = np.random.default_rng(seed_sequence)
    return torch.from_numpy(rng.random((slots, heads)) < 0.5)


def ensemble_critic_loss(
    q: Tensor, rewards: Tensor, terminated: Tensor, next_q: Tensor,
    discount: float | Tensor, mask: Tensor,
) -> tuple[Tensor, Tensor]:  # fmt: skip
    """The heads' loss and the batch's mean |TD error| (of the heads' mean).

    ``q`` and ``next_q`` are (batch, heads): each head's squared error to its own target
    head's TD target, counted only where ``mask`` (batch, heads) says the head learns
    from the sample, averaged over the counted pairs.
    """
    per_sample = discount.unsqueeze(-1) if isinstance(discount, Tensor) else discount
    target = td_target(rewards.unsqueeze(-1), terminated.unsqueeze(-1), next_q, per_sample)
    weight = mask.to(q.dtype)
    loss = (weight * (q - target).square()).sum() / weight.sum().clamp(min=1.0)
    error = (q.detach().mean(-1) - target.mean(-1)).abs().mean()
    return loss, error


def pessimistic_value(values: Tensor, price: float) -> Tensor:
    """The heads' mean minus ``price`` times their standard deviation, per sample."""
    return values.mean(-1) - price * disagreement(values)


def disagreement(values: Tensor) -> Tensor:
    """The heads' standard deviation per sample (over the heads, not a sample estimate)."""
    return values.std(-1, correction=0)
