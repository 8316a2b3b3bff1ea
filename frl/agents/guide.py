"""Imitation terms of the actor's loss: a teacher's (:attr:`frl.agents.DDPGConfig.guide`)
and the agent's own better-than-expected actions (:attr:`~frl.agents.DDPGConfig.self_imitation`).

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
    return _squared_gaps(preactivation, teacher).mean()


def _squared_gaps(preactivation: Tensor, target: Tensor) -> Tensor:
    """Per sample, the squared distance from the actor's output to ``target``, summed over
    the action dimensions, where an output past the bound ``target`` sits at counts as on
    it."""
    gap = preactivation.float() - target
    past_bound = ((target >= 1.0) & (gap > 0)) | ((target <= -1.0) & (gap < 0))
    gap = torch.where(past_bound, torch.zeros_like(gap), gap)
    return gap.square().sum(dim=-1) if gap.dim() > 1 else gap.square()


def self_imitation_loss(
    preactivation: Tensor, taken: Tensor, realised: Tensor, expected: Tensor
) -> tuple[Tensor, Tensor]:
    """Self-imitation (Oh et al. 2018): the squared distance between the actor's action and
    the action ``taken`` (as :func:`imitation_loss` measures it), on the samples whose
    ``realised`` return beat the critic's ``expected`` value of the actor's action; zero on
    the others and where the return is unknown (NaN). A batch mean, so that the term's
    scale follows how often the agent's own driving beat its critic; and that share.
    """
    better = (realised > expected).float()  # NaN compares False
    return (better * _squared_gaps(preactivation, taken)).mean(), better.mean()
