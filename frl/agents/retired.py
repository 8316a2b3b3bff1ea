"""Agent options that frl retired (:mod:`frl.retirement` says how a retired key loads)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from frl.retirement import RetiredOption, RetiredOptionError, retired_message
from frl.retirement import without_retired as _without_retired

RETIRING_COMMIT = "7ff57ca"
"""The commit that removed the first options below (``git show`` it to read their code)."""


_DRIVE_WELL = '"Agents that drive well"'
_LEVERS = '"The rule as a teacher, the task as an input, prioritised replay"'
_UNMEASURED_COMMIT = "bbf4ecc"
_THIRD_COMMIT = "c76bc5e"
_BUDGET = '"A collision budget"'
_BUDGET_COMMIT = "60f3304"
_KEEPABLE_BUDGET = '"A budget the car can keep"'
_KEEPABLE_BUDGET_COMMIT = "f5359cd"
_BRANCHES = '"Counterfactual branches at the entry decision"'
_BRANCHES_COMMIT = "5f21138"
_DOUBT = '"A price on doubt: bootstrapped critic heads"'
_DOUBT_COMMIT = "c23eea2"
_SELF_IMITATION = '"Self-imitation: its own driving that beat its critic"'
_SELF_IMITATION_COMMIT = "bc5ce4d"
_RETURNS = '"The reward critic on what each episode returned"'
_RETURNS_COMMIT = "fd12ff8"
_BANG_BANG = '"Trained bang-bang: every action at full throttle or full brake"'
_BANG_BANG_COMMIT = "3a3a810"
_BRANCHES_OFF = {"probability": 0.0, "before_line_m": 10.0, "past_line_m": 5.0, "hold_steps": 10}
"""The ``agent.branches`` group as every config and checkpoint wrote it with branches off."""

RETIRED_OPTIONS: dict[str, RetiredOption] = {
    "action_repeat": RetiredOption(1, _DRIVE_WELL, RETIRING_COMMIT),
    "explore_hold_probability": RetiredOption(0.0, _DRIVE_WELL, RETIRING_COMMIT),
    "terminal_fraction": RetiredOption(0.0, _DRIVE_WELL, RETIRING_COMMIT),
    "critic_layer_norm": RetiredOption(False, _DRIVE_WELL, RETIRING_COMMIT),
    "warmup_policy": RetiredOption("uniform", _DRIVE_WELL, RETIRING_COMMIT),
    "twin_critics": RetiredOption(False, _DRIVE_WELL, RETIRING_COMMIT),
    "target_noise": RetiredOption(0.0, _DRIVE_WELL, RETIRING_COMMIT),
    "target_noise_clip": RetiredOption(0.5, _DRIVE_WELL, RETIRING_COMMIT),
    "policy_delay": RetiredOption(1, _DRIVE_WELL, RETIRING_COMMIT),
    "replay": RetiredOption("uniform", _LEVERS, RETIRING_COMMIT),
    "lap_alpha": RetiredOption(0.4, _LEVERS, RETIRING_COMMIT),
    "lap_min_priority": RetiredOption(1.0, _LEVERS, RETIRING_COMMIT),
    "guide_residual": RetiredOption(False, _LEVERS, RETIRING_COMMIT),
    "preactivation_l2": RetiredOption(0.0, None, _UNMEASURED_COMMIT),
    "guide_decay_steps": RetiredOption(0, None, _UNMEASURED_COMMIT),
    "guide_filter_margin": RetiredOption(0.0, None, _UNMEASURED_COMMIT),
    "guide_filter": RetiredOption("none", _LEVERS, _THIRD_COMMIT, ("guide_weight", 0)),
    "gradient_steps": RetiredOption(1, _LEVERS, _THIRD_COMMIT),
    "random_warmup": RetiredOption(True, None, _THIRD_COMMIT),
    "average_multiplier": RetiredOption(False, _BUDGET, _BUDGET_COMMIT),
    "budget_noise_free_every": RetiredOption(0, _KEEPABLE_BUDGET, _KEEPABLE_BUDGET_COMMIT),
    "branches": RetiredOption(_BRANCHES_OFF, _BRANCHES, _BRANCHES_COMMIT),
    "self_imitation": RetiredOption(0.0, _SELF_IMITATION, _SELF_IMITATION_COMMIT),
    "reward_target": RetiredOption("n_step", _RETURNS, _RETURNS_COMMIT),
    "bang_bang": RetiredOption(False, _BANG_BANG, _BANG_BANG_COMMIT),
}
"""Each retired key, with its off value and its study."""

RETIRED_CRITIC_OPTIONS: dict[str, RetiredOption] = {
    "heads": RetiredOption(5, _DOUBT, _DOUBT_COMMIT),
    "disagreement_price": RetiredOption(1.0, _DOUBT, _DOUBT_COMMIT),
}
"""Retired keys of the ``agent.critic`` group, with the values every config held."""
RETIRED_CRITIC_KINDS: dict[str, RetiredOption] = {
    "ensemble": RetiredOption("expected", _DOUBT, _DOUBT_COMMIT),
}
"""Retired values of ``agent.critic.kind``: what each measured, and the kind that loads."""


__all__ = [
    "RETIRED_CRITIC_KINDS",
    "RETIRED_CRITIC_OPTIONS",
    "RETIRED_OPTIONS",
    "RetiredOption",
    "RetiredOptionError",
    "without_retired",
    "without_retired_critic",
]


def without_retired(options: Mapping[str, Any]) -> dict[str, Any]:
    """Agent ``options`` less the retired keys set to their off values.

    Raises:
        RetiredOptionError: a retired key at any other value (the first such key).
    """
    return _without_retired(options, RETIRED_OPTIONS, "agent")


def without_retired_critic(critic: Mapping[str, Any]) -> dict[str, Any]:
    """The ``agent.critic`` group's ``critic`` options less its retired keys at their off
    values.

    Raises:
        RetiredOptionError: a retired kind, or a retired key at any other value.
    """
    kind = critic.get("kind")
    if isinstance(kind, str) and kind in RETIRED_CRITIC_KINDS:
        raise RetiredOptionError(
            retired_message("agent.critic", "kind", RETIRED_CRITIC_KINDS[kind], kind)
        )
    return _without_retired(critic, RETIRED_CRITIC_OPTIONS, "agent.critic")
