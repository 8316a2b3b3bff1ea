"""Yardstick policies: what a blind, a rule-based and a clairvoyant driver score.

A trained model means little on its own: these five, tested on the same seeds, say
how far it is from driving blind and from the best any policy could do.

- ``full_throttle``: accelerate from the first step, never brake;
- ``always_brake``: never leave the stop line;
- ``gap_acceptance``: a rule-based driver reading only the paper's grid
  (:class:`GapAcceptancePolicy`);
- ``committed_gap_acceptance``: the same rule told the distance to the stop line, so it
  never waits inside the junction (:class:`CommittedGapAcceptancePolicy`; the env
  supplies the distance when the model under test sees the grid alone);
- ``oracle``: waits with hindsight for the best moment, then goes at full throttle
  (:class:`LookaheadOracle`; it reads the simulation): never collides; the quickest safe
  driver of the "wait, then go" family.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from frl.agents import DDPG
from frl.envs.config import EnvConfig
from frl.envs.intersection import IntersectionEnv
from frl.policies.blind import ConstantPolicy, always_brake, full_throttle
from frl.policies.gap_acceptance import CommittedGapAcceptancePolicy, GapAcceptancePolicy
from frl.policies.oracle import LookaheadOracle, Rollout

Policy = Callable[[np.ndarray], np.ndarray]

YARDSTICKS: tuple[str, ...] = (
    "full_throttle",
    "always_brake",
    "gap_acceptance",
    "committed_gap_acceptance",
    "oracle",
)
"""The yardstick names, in the order tables list them."""

DEFAULT_YARDSTICKS: tuple[str, ...] = (
    "full_throttle",
    "gap_acceptance",
    "committed_gap_acceptance",
    "oracle",
)
"""The yardsticks a test drives beside a model unless told otherwise (``yardsticks``)."""

YARDSTICK_LABELS: dict[str, str] = {
    "full_throttle": "full throttle",
    "always_brake": "always brake",
    "gap_acceptance": "gap acceptance",
    "committed_gap_acceptance": "committed gap acceptance",
    "oracle": "oracle",
}


def make_yardstick(name: str, env: IntersectionEnv) -> Policy:
    """The yardstick ``name`` for episodes on ``env`` (the oracle drives ``env`` itself)."""
    if name == "full_throttle":
        return full_throttle()
    if name == "always_brake":
        return always_brake()
    if name == "gap_acceptance":
        return GapAcceptancePolicy(env.config)
    if name == "committed_gap_acceptance":
        return CommittedGapAcceptancePolicy(
            env.config, stop_line_distance=lambda: env.stop_line_distance_m
        )
    if name == "oracle":
        return LookaheadOracle(env)
    raise ValueError(f"unknown policy {name!r}; choose one of {', '.join(YARDSTICKS)}")


TEACHERS: dict[str, Callable[[EnvConfig], Policy]] = {
    "gap_acceptance": GapAcceptancePolicy,
    "committed_gap_acceptance": CommittedGapAcceptancePolicy,
}
"""The drivers an agent can learn from (``DDPGConfig.guide``), by name."""

TEACHERS_READING_THE_ROUTE: frozenset[str] = frozenset({"committed_gap_acceptance"})
"""Teachers that read the distance to the stop line from the observation: a teacher is
asked on what its student sees, so the student must observe the route too."""


def check_teacher(guide: str, route_observation: bool) -> None:
    """A teacher that reads the route needs a student that observes it.

    Raises:
        ValueError: naming ``env.route_observation``.
    """
    if guide in TEACHERS_READING_THE_ROUTE and not route_observation:
        raise ValueError(
            f"agent.guide={guide} reads the distance to the stop line from the student's "
            "observation: set env.route_observation=true"
        )


def install_guide(agent: DDPG, env: EnvConfig) -> None:
    """Give a guided ``agent`` (``DDPGConfig.guide``) its teacher for the scenario ``env``;
    an agent without a guide is left as it is."""
    if agent.config.guide != "none":
        check_teacher(agent.config.guide, env.route_observation)
        agent.set_guide(TEACHERS[agent.config.guide](env))


def load_model(path: str | os.PathLike[str], env: IntersectionEnv, device: str = "cpu") -> DDPG:
    """The model saved at ``path`` on ``env``'s spaces, a guided one with its teacher
    installed so that it can go on learning: ``load_model(path, env).act(observation,
    explore=False)`` drives it as it is tested."""
    agent = DDPG.from_checkpoint(path, env.observation_space, env.action_space, device=device)
    install_guide(agent, env.config)
    return agent


__all__ = [
    "DEFAULT_YARDSTICKS",
    "TEACHERS",
    "TEACHERS_READING_THE_ROUTE",
    "YARDSTICKS",
    "YARDSTICK_LABELS",
    "CommittedGapAcceptancePolicy",
    "ConstantPolicy",
    "GapAcceptancePolicy",
    "LookaheadOracle",
    "Policy",
    "Rollout",
    "always_brake",
    "check_teacher",
    "full_throttle",
    "install_guide",
    "load_model",
    "make_yardstick",
]
