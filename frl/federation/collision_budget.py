"""Where each vehicle's collision budget stands at the end of training.

Under ``agent.collision_budget`` a vehicle's Lagrange multiplier follows its training
collision rate (:mod:`frl.agents.lagrange`). Whether the budget was met, and whether the
multiplier settled or kept growing (a budget out of the car's reach makes it a penalty
that rises with time), are read here from what the vehicle reports each round: the
episodes that ended in it, the multiplier after its last update and the rate it followed
then (its last ``lagrange_window`` episodes).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from frl.episodes import EpisodeRecord

KEPT_FACTOR = 1.5
"""A budget is kept when the last round's training collision rate is at most this many
times the budget: the rate of a few hundred episodes is noisy, the multiplier acts on a
window of 50 of them."""

LEVELLED_SHARE = 0.1
"""The multiplier has levelled off when it moved over the last round by at most this
share of its value ..."""

LEVELLED_FLOOR = 0.5
"""... or by at most this much (reward units per collision; a crash already costs about
14.5): a multiplier near 0 may move by a little and still be at rest."""


def round_record(
    episodes: Sequence[EpisodeRecord],
    multipliers: np.ndarray | None,
    followed_rates: np.ndarray | None = None,
) -> dict[str, Any]:
    """One vehicle's round: its finished training episodes, their collisions, the
    multiplier after the round's last update and the collision rate it followed then (its
    last ``lagrange_window`` episodes); None without a budget or an update. Episodes its
    teacher drove (``guide_drives``) are counted apart: the budget is the agent's."""
    own = [episode for episode in episodes if not episode.teacher_drove]
    teachers = [episode for episode in episodes if episode.teacher_drove]
    return {
        "episodes": len(own),
        "collisions": int(sum(episode.collision for episode in own)),
        "teacher_episodes": len(teachers),
        "teacher_collisions": int(sum(episode.collision for episode in teachers)),
        "multiplier": _last_known(multipliers),
        "followed_rate": _last_known(followed_rates),
    }


def _last_known(values: np.ndarray | None) -> float | None:
    """The last value of a per-update series that is not NaN (updates without it)."""
    if values is None:
        return None
    known = values[~np.isnan(values)]
    return float(known[-1]) if known.size else None


def budget_end_state(rounds: Sequence[dict[str, Any]], budget: float) -> dict[str, Any]:
    """A vehicle's budget at the end of training, from its :func:`round_record` per round.

    ``kept``: the last round's training collision rate (of the agent's own episodes)
    within :data:`KEPT_FACTOR` times ``budget``; ``followed_collision_rate``: the rate
    the multiplier followed at the end (None for a run recorded before it was kept);
    ``levelled_off``: the multiplier's change over the last round within
    :data:`LEVELLED_SHARE` of its value or :data:`LEVELLED_FLOOR` (None before two rounds
    with a multiplier); ``last_round_teacher_episodes``: the episodes a teacher drove
    then (``guide_drives``), not counted."""
    rates = [r["collisions"] / r["episodes"] if r["episodes"] else None for r in rounds]
    multipliers = [r["multiplier"] for r in rounds]
    followed = rounds[-1].get("followed_rate") if rounds else None  # absent: older runs
    last_rate = rates[-1] if rates else None
    known = [m for m in multipliers if m is not None]
    change = known[-1] - known[-2] if len(known) >= 2 else None
    levelled = None
    if change is not None:
        levelled = abs(change) <= max(LEVELLED_SHARE * abs(known[-1]), LEVELLED_FLOOR)
    return {
        "budget": budget,
        "last_round_collision_rate": last_rate,
        "last_round_teacher_episodes": rounds[-1].get("teacher_episodes", 0) if rounds else 0,
        "followed_collision_rate": followed,
        "kept": None if last_rate is None else last_rate <= KEPT_FACTOR * budget,
        "multiplier": known[-1] if known else None,
        "multiplier_change_last_round": change,
        "levelled_off": levelled,
        "collision_rate_per_round": rates,
        "multiplier_per_round": multipliers,
    }


def budget_lines(end_states: dict[str, dict[str, Any]]) -> list[str]:
    """One line per vehicle, for the log: its last round's rate against the budget and
    where its multiplier stands."""
    lines = []
    for vehicle, end in end_states.items():
        rate = end["last_round_collision_rate"]
        budget = end["budget"]
        kept = {True: "kept", False: "NOT kept", None: "no episode"}[end["kept"]]
        teacher = end.get("last_round_teacher_episodes", 0)
        episodes = f" (its own episodes; its teacher drove {teacher} more)" if teacher else ""
        line = (
            f"{vehicle}: training collisions {_percent(rate)} over its last round{episodes} "
            f"against a budget of {_percent(budget)} ({kept}, at most {KEPT_FACTOR:g} times "
            "the budget)"
        )
        if end["multiplier"] is not None:
            change = end["multiplier_change_last_round"]
            settled = {True: "levelled off", False: "still moving", None: "one round only"}
            line += f"; multiplier {end['multiplier']:.2f}"
            if change is not None:
                line += f" ({change:+.2f} over the last round: {settled[end['levelled_off']]})"
        lines.append(line)
    return lines


def _percent(value: float | None) -> str:
    return "-" if value is None or math.isnan(value) else f"{100 * value:.1f}%"
