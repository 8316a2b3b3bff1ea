"""Episode records and the test metrics of the paper's Section IV.B.

Shared by local training (what a vehicle reports after a round) and evaluation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from frl.envs import IntersectionEnv

TRAVEL_TIME_DEFINITION = (
    "average_travel_time: mean steps (0.2 s each) from departure to arrival over the episodes "
    "that arrived; episodes that collide or time out have no travel time and are counted in "
    "collision_rate and timeout_rate instead (null when no episode arrived). "
    "average_episode_steps: mean steps over all episodes, counting a collision or a time-out "
    "at the step it ended (the paper's Fig. 5(c) convention, which makes collisions look fast)."
)
"""How episodes that do not arrive are counted; written into every results.json."""

METRIC_NAMES: tuple[str, ...] = (
    "average_reward",
    "collision_rate",
    "arrival_rate",
    "timeout_rate",
    "average_travel_time",
    "average_episode_steps",
)


@dataclass(frozen=True)
class EpisodeRecord:
    """One finished episode: scalars only, nothing the vehicle perceived."""

    task: str
    episode_return: float
    collision: bool
    arrived: bool
    timeout: bool
    """Truncated at ``max_episode_steps`` without collision or arrival."""
    steps: int
    """Steps the episode lasted (``info["travel_time_steps"]`` at its end)."""
    end_step: int = 0
    """The client's environment step at which the episode ended (training only)."""
    mean_speed: float | None = None
    """The ego's mean speed over the episode's steps (m/s)."""
    stopped_steps: int | None = None
    """Steps the ego stood still (speed at or below the reward's ``moving_speed``)."""
    critic_bias: float | None = None
    """Training only: mean over the episode's steps of Q(s_t, a_t) - G_t, the critic's
    value against the discounted return actually received; None for a truncated episode
    (its return after the cut is unknown)."""
    teacher_drove: bool = False
    """Training only: a guided agent's teacher drove the episode, not the agent
    (``DDPGConfig.guide_drives``)."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


Policy = Callable[[np.ndarray], np.ndarray]


def run_episode(
    env: IntersectionEnv,
    policy: Policy,
    task: str,
    seed: int | None,
    on_reset: Callable[[], None] | None = None,
) -> EpisodeRecord:
    """Play one episode of ``task`` with ``policy``; ``seed`` restarts SUMO (None continues).

    ``on_reset`` runs after the reset, before the first action (an agent's
    ``episode_start``: a held action must not cross episodes)."""
    observation, info = env.reset(seed=seed, options={"task": task})
    if on_reset is not None:
        on_reset()
    total = 0.0
    speeds = []
    while True:
        observation, reward, terminated, truncated, info = env.step(policy(observation))
        total += float(reward)
        speeds.append(info["ego_speed"])
        if terminated or truncated:
            break
    mean_speed, stopped = speed_summary(speeds, env.reward_config.moving_speed)
    return EpisodeRecord(
        task=info["task"],
        episode_return=total,
        collision=bool(info["collision"]),
        arrived=bool(info["arrived"]),
        timeout=bool(truncated and not terminated),
        steps=int(info["travel_time_steps"]),
        mean_speed=mean_speed,
        stopped_steps=stopped,
    )


def speed_summary(speeds: Sequence[float], moving_speed: float) -> tuple[float, int]:
    """The mean of an episode's per-step ego speeds, and how many steps it stood still."""
    values = np.asarray(speeds, dtype=np.float64)
    return float(values.mean()) if values.size else 0.0, int(np.sum(values <= moving_speed))


def run_episodes(
    env: IntersectionEnv,
    policy: Policy,
    task: str,
    seeds: Iterable[int],
    on_reset: Callable[[], None] | None = None,
) -> list[EpisodeRecord]:
    """One episode per seed, each on freshly restarted SUMO traffic (common random numbers:
    every policy tested with the same seeds meets the same human arrivals)."""
    return [run_episode(env, policy, task, int(seed), on_reset) for seed in seeds]


def summarize(records: Sequence[EpisodeRecord]) -> dict[str, Any]:
    """The Section IV.B metrics of some episodes; see :data:`TRAVEL_TIME_DEFINITION`.

    ``return_std`` (sample standard deviation of the returns, for intervals) is per task
    only: :func:`average_over_tasks` leaves it out.
    """
    count = len(records)
    if count == 0:
        return {name: None for name in METRIC_NAMES} | {"return_std": None, "episodes": 0}
    arrived_steps = [r.steps for r in records if r.arrived]
    returns = [r.episode_return for r in records]
    return {
        "average_reward": float(np.mean(returns)),
        "return_std": float(np.std(returns, ddof=1)) if count > 1 else None,
        "collision_rate": sum(r.collision for r in records) / count,
        "arrival_rate": len(arrived_steps) / count,
        "timeout_rate": sum(r.timeout for r in records) / count,
        "average_travel_time": float(np.mean(arrived_steps)) if arrived_steps else None,
        "average_episode_steps": float(np.mean([r.steps for r in records])),
        "episodes": count,
    }


def average_over_tasks(per_task: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Unweighted mean of each metric over tasks (the paper averages its three models).

    A task with no arrival (travel time ``None``) is left out of the travel-time mean.
    """
    result: dict[str, Any] = {}
    for name in METRIC_NAMES:
        values = [m[name] for m in per_task.values() if m.get(name) is not None]
        result[name] = float(np.mean(values)) if values else None
    result["episodes"] = sum(int(m.get("episodes", 0)) for m in per_task.values())
    return result


def finite_or_none(value: float | None) -> float | None:
    """JSON has no NaN: map non-finite numbers to ``None``."""
    if value is None or not math.isfinite(value):
        return None
    return float(value)
