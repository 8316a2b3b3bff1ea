"""The per-step reward of the paper's Eq. (2), term by term (see :class:`RewardConfig`),
and the step's costs, which a constraint counts apart from the reward."""

from __future__ import annotations

from dataclasses import dataclass

from frl.envs.config import RewardConfig

REWARD_TERMS: tuple[str, ...] = (
    "time", "speed", "disturbance", "undisturbed", "collision", "arrival",
)  # fmt: skip
"""Keys of ``info["reward_terms"]``; their values sum to the step's reward."""

COST_TERMS: tuple[str, ...] = ("collision", "brake_past_line")
"""Keys of ``info["cost_terms"]``; their values sum to ``info["cost"]``, what a collision
budget (``agent.collision_budget``) counts and its cost critic learns."""

BRAKE_PAST_LINE_DEPTH_M = 15.0
"""A brake counts as a brake past the stop line while the ego's nose is past the line by
less than this (its first metres inside the junction, where the committed rule never
brakes; docs/studies.md, "Where the car stands")."""


@dataclass(frozen=True)
class RewardSignals:
    """The raw indicators of one step, each 0 or 1 (see :class:`RewardConfig`)."""

    moving: bool
    others_braking: bool
    others_waiting: bool
    collision: bool
    arrived: bool
    braked_past_line: bool = False
    """The ego braked with its nose past the stop line (:data:`BRAKE_PAST_LINE_DEPTH_M`)."""


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
    per episode, not reward. A brake past the stop line counts ``brake_past_line_cost``
    (0 by default) a step, so that a budget prices waiting inside the junction too."""
    return {
        "collision": float(signals.collision),
        "brake_past_line": config.brake_past_line_cost * signals.braked_past_line,
    }
