"""From observed steps to stored transitions: n-step accumulation and teacher labels.

Each step the agent observes goes through the n-step accumulator
(:class:`frl.agents.n_step.NStepAccumulator`), which hands back the transitions that are
complete; a guided agent's teacher labels each with its action at the first state before
it enters the replay buffer.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from frl.agents.acting import ActionScale
from frl.agents.n_step import NStepAccumulator, Transition
from frl.agents.observations import ObservationLayout
from frl.agents.replay_buffer import ReplayBuffer


class Teacher:
    """A guided agent's teacher asked on stored (flat) observations, its actions normalised.

    ``driver`` maps an observation as the environment gives it to an env action; it is
    installed later (``DDPG.set_guide``), by whoever builds the environment.
    """

    def __init__(self, name: str, layout: ObservationLayout, scale: ActionScale) -> None:
        self.name, self.layout, self.scale = name, layout, scale
        self.driver: Callable[[Any], Any] | None = None

    def __call__(self, flat: np.ndarray) -> np.ndarray:
        if self.driver is None:
            raise RuntimeError(
                f"guide={self.name!r} needs the teacher: call agent.set_guide(policy) first "
                "(frl's vehicles do; frl.policies.install_guide(agent, env_config) for a "
                "loaded agent)"
            )
        observation = self.layout.unflat(flat)
        if self.layout.parts is None:  # a Box's observation, whether stored flat or not
            observation = np.asarray(observation).reshape(self.layout.shape)
        return self.scale.to_unit(self.driver(observation)).astype(np.float32)


class TransitionWriter:
    """Writes one environment step at a time into ``buffer`` as n-step transitions.

    Args:
        buffer: where complete transitions go.
        n_step: steps summed in each transition (1: one-step transitions).
        gamma: the discount inside an n-step reward.
        teacher: labels every transition with the teacher's action at ``obs`` (a guided
            agent); None: no labels.
        hold_episode: write each episode's transitions when it ends, those of an episode
            that terminated with their discounted cost to its end (the buffer must keep
            it: ``ReplayBuffer(costs_to_go=True)``).
    """

    def __init__(
        self, buffer: ReplayBuffer, n_step: int, gamma: float, teacher: Teacher | None = None,
        hold_episode: bool = False,
    ) -> None:  # fmt: skip
        if hold_episode and not buffer.costs_to_go:
            raise ValueError(
                "holding episodes for their costs to go needs a buffer that keeps them"
            )
        self.buffer = buffer
        self.pending = NStepAccumulator(n_step, gamma, hold_episode)
        """The running episode's steps not yet written as transitions."""
        self.teacher = teacher

    def write(
        self, obs: np.ndarray, action: np.ndarray, reward: float, next_obs: np.ndarray,
        terminated: bool, cost: float = 0.0,
    ) -> None:  # fmt: skip
        """One step (``action`` normalised). ``terminated`` excludes time-limit cut-offs,
        which must still bootstrap; ``cost``: the step's collisions, where counted."""
        for transition in self.pending.push(obs, action, reward, next_obs, terminated, 1, cost):
            self._store(transition)

    def end_episode(self) -> None:
        """The episode was cut off (a time limit, a new episode): its pending steps become
        transitions that bootstrap from the last state reached."""
        for transition in self.pending.flush():
            self._store(transition)

    def _store(self, transition: Transition) -> None:
        obs, action, reward, next_obs, terminated, horizon, cost, cost_to_go = transition
        label = None if self.teacher is None else self.teacher(obs)
        final = cost_to_go is not None
        self.buffer.add(
            obs, action, reward, next_obs, terminated, horizon, label,
            cost_to_go if final else cost, final,
        )  # fmt: skip
