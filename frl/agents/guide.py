"""Learning from a teacher: the imitation term of the actor's loss
(:attr:`frl.agents.DDPGConfig.guide`).

Tensor maths, tested against hand-computed numbers in tests/test_agent_guide.py. Actions
are in the actor's normalised units, [-1, 1].
"""

from __future__ import annotations

import torch
from torch import Tensor


def imitation_loss(preactivation: Tensor, teacher: Tensor) -> Tensor:
    """Batch mean of ``(preactivation - teacher)**2`` summed over the action dimensions,
    in float32 (the actor's output layer is float32 under autocast too).

    The actor's output is clipped to [-1, 1]: where the teacher sits at a bound, an output
    already past it takes that action too and is not pulled back.
    """
    gap = preactivation.float() - teacher
    past_bound = ((teacher >= 1.0) & (gap > 0)) | ((teacher <= -1.0) & (gap < 0))
    gap = torch.where(past_bound, torch.zeros_like(gap), gap)
    per_sample = gap.square().sum(dim=-1) if gap.dim() > 1 else gap.square()
    return per_sample.mean()
