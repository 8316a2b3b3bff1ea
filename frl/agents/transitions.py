"""From observed steps to stored transitions: n-step accumulation and teacher labels.

Each step the agent observes goes through the n-step accumulator
(:class:`frl.agents.n_step.NStepAccumulator`), which hands back the transitions that are
complete; a guided agent's teacher labels each with its actions at both ends before it
enters the replay buffer.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from frl.agents.n_step import NStepAccumulator
from frl.agents.replay_buffer import ReplayBuffer

Teacher = Callable[[np.ndarray], np.ndarray]
"""A flat observation -> the teacher's action there, normalised to [-1, 1]."""


class TransitionWriter:
    """Writes one environment step at a time into ``buffer`` as n-step transitions.

    Args:
        buffer: where complete transitions go.
        n_step: steps summed in each transition (1: one-step transitions).
        gamma: the discount inside an n-step reward.
        teacher: labels every transition with the teacher's actions at ``obs`` and
            ``next_obs`` (a guided agent); None: no labels.
    """

    def __init__(
        self, buffer: ReplayBuffer, n_step: int, gamma: float, teacher: Teacher | None = None
    ) -> None:
        self.buffer = buffer
        self.pending = NStepAccumulator(n_step, gamma)
        """The running episode's last steps, not yet a complete transition."""
        self.teacher = teacher

    def write(
        self, obs: np.ndarray, action: np.ndarray, reward: float, next_obs: np.ndarray,
        terminated: bool,
    ) -> None:  # fmt: skip
        """One step (``action`` normalised). ``terminated`` excludes time-limit cut-offs,
        which must still bootstrap."""
        for transition in self.pending.push(obs, action, reward, next_obs, terminated):
            self._store(*transition)

    def end_episode(self) -> None:
        """The episode was cut off (a time limit, a new episode): its pending steps become
        transitions that bootstrap from the last state reached."""
        for transition in self.pending.flush():
            self._store(*transition)

    def _store(
        self, obs: np.ndarray, action: np.ndarray, reward: float, next_obs: np.ndarray,
        terminated: bool, horizon: int,
    ) -> None:  # fmt: skip
        labels: tuple[np.ndarray, ...] = ()
        if self.teacher is not None:
            labels = (self.teacher(obs), self.teacher(next_obs))
        self.buffer.add(obs, action, reward, next_obs, terminated, horizon, *labels)
