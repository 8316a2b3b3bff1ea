"""The per-step reward of the paper's Eq. (2), term by term (see :class:`RewardConfig`),
and the step's costs, which a constraint counts apart from the reward."""

from __future__ import annotations

from dataclasses import dataclass

from frl.envs.config import RewardConfig

REWARD_TERMS: tuple[str, ...] = (
    "time", "speed", "disturbance", "undisturbed", "collision", "arrival",
)  # fmt: skip
"""Keys of ``info["reward_terms"]``; their values sum to the step's reward."""

COST_TERMS: tuple[str, ...] = ("collision",)
"""Keys of ``info["cost_terms"]``; their values sum to ``info["cost"]``, what a collision
budget (``agent.collision_budget``) counts and its cost critic learns."""


@dataclass(frozen=True)
class RewardSignals:
    """The raw indicators of one step, each 0 or 1 (see :class:`RewardConfig`)."""

    moving: bool
    others_braking: bool
    others_waiting: bool
    collision: bool
    arrived: bool


def reward_terms(signals: RewardSignals, config: RewardConfig) -> dict[str, float]:
    """Each weighted term of the reward: alpha*t, beta*v, gamma*(b+w), kappa*u, lambda*c, mu*d."""
    disturbed = int(signals.others_braking) + int(signals.others_waiting)
    return {
        "time": config.alpha,
        "speed": config.beta * signals.moving,
        "disturbance": config.gamma * disturbed,
        "undisturbed": config.undisturbed_bonus * (disturbed == 0),
        "collision": config.lambda_ * signals.collision,
        "arrival": config.mu * signals.arrived,
    }


def cost_terms(signals: RewardSignals, config: RewardConfig) -> dict[str, float]:
    """Each cost of the step. A collision counts 1: the constraint's units are collisions
    per episode, not reward. A second cost is one more entry (and one in :data:`COST_TERMS`)."""
    return {"collision": float(signals.collision)}
