"""Learning from a teacher: the imitation term of the actor's loss and its Q-filter
(:attr:`frl.agents.DDPGConfig.guide`).

Tensor maths, tested against hand-computed numbers in tests/test_agent_guide.py. Actions
are in the actor's normalised units, [-1, 1].
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any

import torch
from torch import Tensor


def q_filter(q_teacher: Tensor, q_actor: Tensor) -> Tensor:
    """1.0 where the imitation term applies, 0.0 where the actor may leave the teacher:
    where the critic rates the actor's action above the teacher's (Nair et al. 2018)."""
    return (q_actor <= q_teacher).float()


def lower_only(mask: Tensor, actor_action: Tensor, teacher: Tensor) -> Tensor:
    """``mask`` (1.0: imitate) where the actor may leave the teacher only towards lower
    actions: it is kept 1.0 wherever the actor's action is not below the teacher's in every
    dimension (for the intersection: wherever the actor would not brake harder)."""
    below = (actor_action <= teacher).all(dim=-1) & (actor_action < teacher).any(dim=-1)
    return torch.where(below, mask, torch.ones_like(mask))


def imitation_loss(preactivation: Tensor, teacher: Tensor, mask: Tensor) -> Tensor:
    """Batch mean of ``mask * (preactivation - teacher)**2`` over the action dimensions.

    The actor's output is clipped to [-1, 1]: where the teacher sits at a bound, an output
    already past it takes that action too and is not pulled back.
    """
    gap = preactivation - teacher
    past_bound = ((teacher >= 1.0) & (gap > 0)) | ((teacher <= -1.0) & (gap < 0))
    gap = torch.where(past_bound, torch.zeros_like(gap), gap)
    per_sample = gap.square().sum(dim=-1) if gap.dim() > 1 else gap.square()
    return (mask * per_sample).mean()


def imitation_term(
    config: Any, critic: Callable[[Any, Tensor], Tensor], batch: Any, preactivation: Tensor,
    q_actor: Tensor, autocast: Callable[[], AbstractContextManager[Any]],
) -> tuple[Tensor, Tensor]:  # fmt: skip
    """The imitation term at full weight (the caller scales it by ``guide_weight``) and
    the share of the batch it reaches: everywhere with ``guide_filter=none``, else where
    the critic does not prefer the actor's action (``q_actor``) to the teacher's
    (``batch.guide_actions``), and for ``q_lower``
    also wherever the actor would not brake harder than the teacher. The critic runs in
    ``autocast()``, the update's precision."""
    teacher = batch.guide_actions
    mask = torch.ones(teacher.shape[0], device=teacher.device)
    if config.guide_filter in ("q", "q_lower"):
        with torch.no_grad(), autocast():
            q_teacher = critic(batch.obs, teacher)
        mask = q_filter(q_teacher, q_actor.detach())
        if config.guide_filter == "q_lower":
            actor_action = preactivation.detach().float().clamp(-1.0, 1.0)
            mask = lower_only(mask, actor_action, teacher)
    return imitation_loss(preactivation.float(), teacher, mask), mask.mean()
