"""Traffic that changes as a vehicle trains (``federation.round_arrival_period_factors``).

Each entry scales the humans' mean arrival period in one round of a vehicle's own training
(0.6: a car every 0.6 times as long, busier); a shorter list holds its last entry for the
rounds after it. A vehicle takes the traffic of the round an episode starts in, so an
episode that runs across a round's end finishes in the traffic it began in. Tests always
run on the run's own traffic.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from frl.envs import EnvConfig


def round_factor(factors: Sequence[float], round_index: int) -> float:
    """The factor of 0-based round ``round_index``: its entry, or the list's last one."""
    return factors[min(round_index, len(factors) - 1)]


def scheduled_env(
    env: EnvConfig, factors: Sequence[float], round_steps: int, env_steps: int
) -> EnvConfig:
    """The environment a vehicle whose own traffic is ``env`` drives in an episode that
    starts after ``env_steps`` steps of its training; ``env`` itself without a schedule."""
    if not factors:
        return env
    return with_period_factor(env, round_factor(factors, env_steps // round_steps))


def with_period_factor(env: EnvConfig, factor: float) -> EnvConfig:
    """``env`` with its humans' mean arrival period times ``factor`` (``env`` at 1)."""
    if factor == 1.0:
        return env
    return with_arrival_period(env, env.scenario.human_arrival_period_steps * factor)


def with_arrival_period(env: EnvConfig, period_steps: float) -> EnvConfig:
    """``env`` with its humans' mean arrival period set to ``period_steps``."""
    scenario = dataclasses.replace(env.scenario, human_arrival_period_steps=period_steps)
    return dataclasses.replace(env, scenario=scenario)


def describe_schedule(factors: Sequence[float], num_rounds: int) -> str:
    """The schedule in words for the training log, e.g. ``rounds 1-3 at 0.6 times the
    humans' arrival period, rounds 4-5 at the run's``."""
    per_round = [round_factor(factors, r) for r in range(num_rounds)]
    spans: list[tuple[int, int, float]] = []
    for number, factor in enumerate(per_round, start=1):
        if spans and spans[-1][2] == factor:
            spans[-1] = (spans[-1][0], number, factor)
        else:
            spans.append((number, number, factor))
    parts = []
    for first, last, factor in spans:
        rounds = f"round {first}" if first == last else f"rounds {first}-{last}"
        at = "the run's" if factor == 1.0 else f"{factor:g} times the humans' arrival period"
        parts.append(f"{rounds} at {at}")
    return ", ".join(parts)
