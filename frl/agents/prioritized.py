"""Loss-adjusted prioritised replay (LAP; Fujimoto et al. 2020, "An Equivalence between
Loss Functions and Non-Uniform Sampling in Experience Replay", as TD7 uses it, 2023).

Each transition is drawn with probability proportional to ``max(|delta|, m) ** alpha``,
its last TD error ``delta`` clipped below at the minimum priority ``m``, new transitions at
the largest priority stored; the critic then minimises a Huber loss of threshold ``m``
instead of the squared error. The pair leaves the expected gradient of the uniform
squared-error update on transitions with small errors and samples those with large ones
(here: the rare collisions, about 0.3% of transitions) more often, with no importance
weights. Pure functions, tested against hand-computed numbers.
"""

from __future__ import annotations

import numpy as np
import torch.nn.functional as F
from torch import Tensor


def lap_priority(td_abs: np.ndarray, alpha: float, min_priority: float) -> np.ndarray:
    """``max(|delta|, min_priority) ** alpha`` per transition (float32)."""
    return np.power(np.maximum(np.asarray(td_abs, np.float64), min_priority), alpha).astype(
        np.float32
    )


def lap_critic_loss(q: Tensor, target: Tensor, min_priority: float) -> Tensor:
    """The Huber loss of threshold ``min_priority``: quadratic below it, linear above."""
    return F.huber_loss(q, target, delta=min_priority)


def proportional_slots(
    priorities: np.ndarray, batch_size: int, rng: np.random.Generator
) -> np.ndarray:
    """``batch_size`` indices drawn with replacement in proportion to ``priorities``."""
    cumulative = np.cumsum(priorities, dtype=np.float64)
    draws = rng.uniform(0.0, cumulative[-1], size=batch_size)
    slots = np.searchsorted(cumulative, draws, side="right")
    return np.minimum(slots, len(priorities) - 1)


__all__ = ["lap_critic_loss", "lap_priority", "proportional_slots"]
