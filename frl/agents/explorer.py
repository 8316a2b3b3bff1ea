"""Exploration: the warm-up's held uniform actions, then the policy's action plus noise.

The explorer owns every random stream of acting: the noise process (OU or Gaussian, its
own generator) and the warm-up's generator. Actions are in the actor's normalised units,
[-1, 1]; the agent scales them to the action space.
"""

from __future__ import annotations

import copy

import numpy as np

from frl.agents.config import DDPGConfig
from frl.agents.noise import make_noise


class Explorer:
    """What an exploring agent does to its policy's action.

    Before ``learning_starts`` transitions it drives uniform actions, each held for a
    geometric number of steps of mean ``warmup_hold_steps``, as SB3 and CleanRL act at
    random then, so the first updates see diverse actions; after it, the policy's action
    plus the noise, clipped to [-1, 1].
    """

    def __init__(
        self,
        config: DDPGConfig,
        action_dim: int,
        noise_rng: np.random.Generator,
        warmup_rng: np.random.Generator,
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

    def in_warmup(self, num_env_steps: int) -> bool:
        """Whether the next exploring action is a warm-up one."""
        return num_env_steps < self.config.learning_starts

    def warmup_action(self) -> np.ndarray:
        """A uniform action, held for a geometric number of steps (mean
        ``warmup_hold_steps``; a fresh one every step at 1)."""
        hold = self.config.warmup_hold_steps
        if self.held_action is None or hold <= 1 or self.warmup_rng.random() < 1 / hold:
            self.held_action = self.warmup_rng.uniform(-1.0, 1.0, size=self.action_dim)
        return self.held_action

    def noisy(self, policy_action: np.ndarray) -> np.ndarray:
        """The policy's action plus the next draw of the noise process, within [-1, 1]."""
        return np.clip(policy_action + self.noise(), -1.0, 1.0)

    def noisy_copies(self, policy_actions: np.ndarray) -> np.ndarray:
        """``policy_actions`` (a batch) each plus a draw from a copy of the noise process:
        what exploration would add next, leaving the explorer itself as it was."""
        noise = copy.deepcopy(self.noise)
        return np.clip(policy_actions + np.stack([noise() for _ in policy_actions]), -1, 1)

    def episode_start(self) -> None:
        """A new episode: the noise restarts (OU returns to its mean), no action is held."""
        self.held_action = None
        self.noise.reset()
