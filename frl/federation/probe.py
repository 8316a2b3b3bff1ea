"""The counterfactual probe: "go" against "brake" from the learner's own approach states.

A crash is rare in a vehicle's own driving, and the cost critic learns what a gap is
worth from the few it meets. The probe makes each approach a controlled experiment
(Go-Explore's "return, then explore"; rollout-based policy iteration): at a state the
learner reached on its way to the stop line, it snapshots the simulation, drives one
branch that holds full throttle ("go") and one that holds full brake ("wait") for
``hold_steps`` steps, each followed by the deterministic policy, stores both in the
replay buffer, and puts the simulation back to go on with the episode as it was. A branch
holds its action because one step of either changes the speed by 0.2 m/s only: the
policy that follows would undo the difference.

A snapshot replays every command since SUMO last started (:meth:`IntersectionEnv.restore`),
so a vehicle that probes restarts SUMO with a seed of its own at every training episode,
as test episodes do, and a restore replays one episode. The branches are data only: they
neither count as environment steps of the budget nor move the collision budget's
multiplier, which follows the vehicle's own driving.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any

import numpy as np

from frl.agents import DDPG
from frl.envs import IntersectionEnv

BRANCHES: tuple[str, ...] = ("go", "wait")
"""The held action of each branch: full throttle, full brake."""


@dataclass(frozen=True)
class ProbeConfig:
    """When and how far a vehicle probes (``probe.*`` of the training config)."""

    rate: float = 0.0
    """Chance of a probe at each approach state after the warm-up; 0: no probe."""
    distance_m: float = 10.0
    """The approach: states at most this far before the stop line (the ego starts
    ``env.scenario.ego_start_distance`` = 10 m before it)."""
    hold_steps: int = 10
    """Steps each branch holds its action (2 s at the default step length)."""
    horizon: int = 30
    """Steps each branch drives in all before it stops, unless its episode ends first;
    its last transitions bootstrap from the critics, as a time limit's do."""
    per_episode: int = 1
    """Most probes in one training episode."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.rate <= 1.0:
            raise ValueError(f"probe.rate must be within [0, 1], got {self.rate!r}")
        if not self.distance_m > 0:
            raise ValueError(f"probe.distance_m must be positive, got {self.distance_m!r}")
        for name in ("hold_steps", "horizon", "per_episode"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"probe.{name} must be a positive integer, got {value!r}")
        if self.hold_steps > self.horizon:
            raise ValueError(
                f"probe.hold_steps ({self.hold_steps}) must be at most probe.horizon "
                f"({self.horizon})"
            )

    @property
    def enabled(self) -> bool:
        return self.rate > 0


@dataclass
class ProbeTally:
    """What a vehicle's probes did: probes taken, branch steps driven, branch crashes."""

    probes: int = 0
    steps: int = 0
    go_collisions: int = 0
    wait_collisions: int = 0

    def to_dict(self) -> dict[str, int]:
        return {
            "probes": self.probes,
            "steps": self.steps,
            "go_collisions": self.go_collisions,
            "wait_collisions": self.wait_collisions,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ProbeTally:
        return cls(**{key: int(value) for key, value in data.items()})


class CounterfactualProbe:
    """One vehicle's probe over its environment and agent.

    Args:
        config: when and how far to probe (``config.enabled`` must hold).
        env: the vehicle's environment, on a seeded episode.
        agent: the learner; its buffer receives the branches through a writer of their own.
        rng: decides which approach states are probed (kept in the vehicle's drive).
    """

    def __init__(
        self, config: ProbeConfig, env: IntersectionEnv, agent: DDPG, rng: np.random.Generator
    ) -> None:
        if not config.enabled:
            raise ValueError("a CounterfactualProbe needs probe.rate > 0")
        self.config, self.env, self.agent, self.rng = config, env, agent, rng
        self.writer = agent.branch_writer()
        self.episode_probes = 0
        self.tally = ProbeTally()
        low, high = env.action_space.low, env.action_space.high
        self._held_actions = {"go": high.copy(), "wait": low.copy()}

    def episode_start(self) -> None:
        self.episode_probes = 0

    def maybe_probe(self, observation: Any) -> bool:
        """Probe at ``observation`` (the env's current state) if it is due; whether it was.

        The env is back where it was afterwards, to the last command and random draw."""
        distance = self.env.distance_to_stop_line
        if (
            self.episode_probes >= self.config.per_episode
            or self.agent.explorer.in_warmup(self.agent.num_env_steps)
            or not 0.0 < distance <= self.config.distance_m
            or self.rng.random() >= self.config.rate
        ):
            return False
        snapshot = self.env.snapshot()
        for branch in BRANCHES:
            if self._drive_branch(observation, self._held_actions[branch]):
                if branch == "go":
                    self.tally.go_collisions += 1
                else:
                    self.tally.wait_collisions += 1
            self.env.restore(snapshot)
        self.episode_probes += 1
        self.tally.probes += 1
        return True

    def _drive_branch(self, observation: Any, held_action: np.ndarray) -> bool:
        """Drive one branch from ``observation`` and store it; whether it crashed."""
        agent = self.agent
        for step in range(self.config.horizon):
            if step < self.config.hold_steps:
                action = held_action
            else:
                action, _ = agent.predict(observation)  # leaves the agent as it was
            next_observation, reward, terminated, truncated, info = self.env.step(action)
            agent.observe_branch(
                self.writer, observation, action, float(reward), next_observation,
                terminated, info["cost"],
            )  # fmt: skip
            self.tally.steps += 1
            if terminated or truncated:
                break
            observation = next_observation
        self.writer.end_episode()
        return bool(info["collision"])

    def state(self) -> dict[str, Any]:
        """What an exact resume needs: the generator and this episode's probes."""
        return {
            "rng": copy.deepcopy(self.rng.bit_generator.state),
            "episode_probes": self.episode_probes,
            "tally": self.tally.to_dict(),
        }

    def load_state(self, state: dict[str, Any]) -> None:
        self.rng.bit_generator.state = copy.deepcopy(state["rng"])
        self.episode_probes = int(state["episode_probes"])
        self.tally = ProbeTally.from_dict(state["tally"])
