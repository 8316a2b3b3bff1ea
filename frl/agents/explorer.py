"""Exploration: the warm-up's held uniform actions, then the policy's action plus noise.

The explorer owns every random stream of acting: the noise process (OU or Gaussian, its
own generator), the warm-up's generator, and the generator that decides who drives an
episode where a teacher takes the wheel for a share of them (``guide_drives``). Actions
are in the actor's normalised units, [-1, 1]; the agent scales them to the action space.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from frl.agents.config import DDPGConfig
from frl.agents.noise import generator_state, make_noise, set_generator_state


class Explorer:
    """What an exploring agent does to its policy's action.

    Before ``learning_starts`` transitions it drives uniform actions, each held for a
    geometric number of steps of mean ``warmup_hold_steps``, as SB3 and CleanRL act at
    random then, so the first updates see diverse actions; after it, the policy's action
    plus the noise, clipped to [-1, 1]. Where a teacher drives a share of the episodes
    (``guide_drives``), the action the noise is added to is the teacher's in those.
    """

    def __init__(
        self,
        config: DDPGConfig,
        action_dim: int,
        noise_rng: np.random.Generator,
        warmup_rng: np.random.Generator,
        wheel_rng: np.random.Generator,
    ) -> None:
        self.config = config
        self.action_dim = action_dim
        self.noise = make_noise(
            config.noise.kind,
            (action_dim,),
            noise_rng,
            sigma=config.noise.sigma,
            theta=config.noise.theta,
            dt=config.noise.dt,
        )
        self.warmup_rng = warmup_rng
        self.held_action: np.ndarray | None = None
        """The warm-up action being held (checkpoints keep it)."""
        self.wheel_rng = wheel_rng
        self.wheel_undecided = True
        """Whether the running episode's driver is still to be drawn (at its first
        exploring step after the warm-up; an episode begun in the warm-up is the agent's)."""
        self.teacher_driving = False
        """Whether the teacher drives the running episode."""

    def in_warmup(self, num_env_steps: int) -> bool:
        """Whether the next exploring action is a warm-up one."""
        return num_env_steps < self.config.learning_starts

    def warmup_action(self) -> np.ndarray:
        """A uniform action, held for a geometric number of steps (mean
        ``warmup_hold_steps``; a fresh one every step at 1)."""
        hold = self.config.warmup_hold_steps
        if self.held_action is None or hold <= 1 or self.warmup_rng.random() < 1 / hold:
            self.held_action = self.warmup_rng.uniform(-1.0, 1.0, size=self.action_dim)
        self.wheel_undecided = False
        return self.held_action

    def teacher_at_wheel(self) -> bool:
        """Whether the teacher drives this exploring step: drawn once an episode, at its
        first such step, so that testing (which never explores) draws nothing."""
        if self.wheel_undecided:
            self.wheel_undecided = False
            share = self.config.guide_drives
            self.teacher_driving = share > 0 and bool(self.wheel_rng.random() < share)
        return self.teacher_driving

    def noisy(self, policy_action: np.ndarray) -> np.ndarray:
        """The policy's action plus the next draw of the noise process, within [-1, 1]."""
        return np.clip(policy_action + self.noise(), -1.0, 1.0)

    def noisy_copies(self, policy_actions: np.ndarray) -> np.ndarray:
        """``policy_actions`` (a batch) each plus a draw from a copy of the noise process:
        what exploration would add next, leaving the explorer itself as it was."""
        noise = copy.deepcopy(self.noise)
        return np.clip(policy_actions + np.stack([noise() for _ in policy_actions]), -1, 1)

    def episode_start(self) -> None:
        """A new episode: the noise restarts (OU returns to its mean), no action is held,
        its driver is not drawn yet."""
        self.held_action = None
        self.noise.reset()
        self.wheel_undecided, self.teacher_driving = True, False

    def state_dict(self) -> dict[str, Any]:
        """Who drives the running episode, and the generator that draws it (checkpoints
        keep the noise, the warm-up's generator and the held action on their own)."""
        return {
            "wheel_rng": generator_state(self.wheel_rng),
            "wheel_undecided": self.wheel_undecided,
            "teacher_driving": self.teacher_driving,
        }

    def load_state_dict(self, state: dict[str, Any] | None) -> None:
        """Restore :meth:`state_dict`; None (a checkpoint written before teachers drove):
        the agent drives the running episode."""
        if state is None:
            self.wheel_undecided, self.teacher_driving = False, False
            return
        set_generator_state(self.wheel_rng, state["wheel_rng"])
        self.wheel_undecided = bool(state["wheel_undecided"])
        self.teacher_driving = bool(state["teacher_driving"])
