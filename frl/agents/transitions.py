"""From observed steps to stored transitions: n-step accumulation and teacher labels.

Each step the agent observes goes through the n-step accumulator
(:class:`frl.agents.n_step.NStepAccumulator`), which hands back the transitions that are
complete; a guided agent's teacher labels each with its action at the first state before
it enters the replay buffer. Where the buffer keeps returns to go (self-imitation),
:class:`EpisodeReturns` labels the episode's transitions once it has ended.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from frl.agents.acting import ActionScale
from frl.agents.n_step import NStepAccumulator
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


class EpisodeReturns:
    """The running episode's one-step rewards and the buffer slots its transitions went
    to; when the episode ends (it arrived or collided), each transition's realised
    discounted return to the end goes into the buffer. An episode cut off
    (a time limit) has no realised return: its transitions stay unknown (NaN).

    The k-th transition an episode stores starts at its k-th step: the n-step accumulator
    hands them back in order.
    """

    def __init__(self, buffer: ReplayBuffer, gamma: float) -> None:
        self.buffer, self.gamma = buffer, gamma
        self.rewards: list[float] = []
        self.slots: list[int] = []

    def step(self, reward: float) -> None:
        """One environment step of the running episode."""
        self.rewards.append(reward)

    def stored(self, slot: int) -> None:
        """The running episode's next transition went to ``slot``."""
        self.slots.append(slot)

    def episode_ends(self, terminated: bool) -> None:
        """The episode ended: where it ``terminated``, label its transitions; forget it."""
        if terminated and self.slots:
            if len(self.slots) != len(self.rewards):
                raise RuntimeError(
                    f"{len(self.slots)} transitions stored for {len(self.rewards)} steps"
                )
            returns = self._discounted(self.rewards)
            # An episode longer than the buffer overwrote its own first slots.
            keep = min(len(self.slots), self.buffer.capacity)
            self.buffer.set_returns(np.asarray(self.slots[-keep:]), returns[-keep:])
        self.rewards, self.slots = [], []

    def _discounted(self, values: list[float]) -> np.ndarray:
        """G_t = v_t + gamma G_{t+1}, from each step to the end."""
        out = np.empty(len(values))
        running = 0.0
        for t in range(len(values) - 1, -1, -1):
            running = values[t] + self.gamma * running
            out[t] = running
        return out

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The running episode so far (checkpoints load with ``weights_only=True``)."""
        return {
            "rewards": torch.tensor(self.rewards, dtype=torch.float64),
            "slots": torch.tensor(self.slots, dtype=torch.int64),
        }

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.rewards = [float(v) for v in state["rewards"]]
        self.slots = [int(v) for v in state["slots"]]


class TransitionWriter:
    """Writes one environment step at a time into ``buffer`` as n-step transitions.

    Args:
        buffer: where complete transitions go.
        n_step: steps summed in each transition (1: one-step transitions).
        gamma: the discount inside an n-step reward.
        teacher: labels every transition with the teacher's action at ``obs`` (a guided
            agent); None: no labels.

    Where ``buffer`` keeps returns to go, :attr:`returns` labels each ended episode's.
    """

    def __init__(
        self, buffer: ReplayBuffer, n_step: int, gamma: float, teacher: Teacher | None = None
    ) -> None:
        self.buffer = buffer
        self.pending = NStepAccumulator(n_step, gamma)
        """The running episode's last steps, not yet a complete transition."""
        self.teacher = teacher
        self.returns = EpisodeReturns(buffer, gamma) if buffer.tracks_returns else None
        """The running episode, for its returns to go; None where the buffer keeps none."""

    def write(
        self, obs: np.ndarray, action: np.ndarray, reward: float, next_obs: np.ndarray,
        terminated: bool, cost: float = 0.0,
    ) -> None:  # fmt: skip
        """One step (``action`` normalised). ``terminated`` excludes time-limit cut-offs,
        which must still bootstrap; ``cost``: the step's collisions, where counted."""
        if self.returns is not None:
            self.returns.step(reward)
        for transition in self.pending.push(obs, action, reward, next_obs, terminated, 1, cost):
            self._store(*transition)
        if terminated and self.returns is not None:
            self.returns.episode_ends(terminated=True)

    def end_episode(self) -> None:
        """The episode was cut off (a time limit, a new episode): its pending steps become
        transitions that bootstrap from the last state reached."""
        for transition in self.pending.flush():
            self._store(*transition)
        if self.returns is not None:
            self.returns.episode_ends(terminated=False)

    def _store(
        self, obs: np.ndarray, action: np.ndarray, reward: float, next_obs: np.ndarray,
        terminated: bool, horizon: int, cost: float,
    ) -> None:  # fmt: skip
        label = None if self.teacher is None else self.teacher(obs)
        if self.returns is not None:
            self.returns.stored(self.buffer.pos)
        self.buffer.add(obs, action, reward, next_obs, terminated, horizon, label, cost)
