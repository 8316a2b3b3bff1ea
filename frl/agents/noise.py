"""Exploration noise with its own random generator, in normalised action units."""

from __future__ import annotations

import json
from typing import Any

import numpy as np


def generator_state(rng: np.random.Generator) -> str:
    """A numpy generator's bit-generator state as JSON text (128-bit ints survive as text)."""
    return json.dumps(rng.bit_generator.state)


def set_generator_state(rng: np.random.Generator, state: str) -> None:
    """Restore a state written by :func:`generator_state`."""
    rng.bit_generator.state = json.loads(state)


class OrnsteinUhlenbeckNoise:
    """Euler-Maruyama Ornstein-Uhlenbeck process, as in keras-rl and Stable-Baselines3.

    ``x <- x + theta * (mu - x) * dt + sigma * sqrt(dt) * N(0, 1)``, starting from ``mu``.
    With ``a = 1 - theta * dt`` this is an AR(1) process whose exact stationary variance is
    ``sigma**2 * dt / (1 - a**2)``, which tends to the continuous ``sigma**2 / (2 * theta)``
    as ``dt -> 0``. Temporally correlated noise suits inertial control (acceleration).
    """

    def __init__(
        self,
        shape: tuple[int, ...],
        rng: np.random.Generator,
        theta: float = 0.15,
        sigma: float = 0.3,
        dt: float = 1e-2,
        mu: float = 0.0,
    ) -> None:
        self.shape = tuple(shape)
        self.rng = rng
        self.theta, self.sigma, self.dt, self.mu = theta, sigma, dt, mu
        self.state = np.full(self.shape, mu, dtype=np.float64)

    @property
    def stationary_variance(self) -> float:
        """Exact stationary variance of the discretised process."""
        a = 1.0 - self.theta * self.dt
        if abs(a) >= 1.0:
            return float("inf")
        return self.sigma**2 * self.dt / (1.0 - a * a)

    def reset(self) -> None:
        """Restart from ``mu``; call at every episode start."""
        self.state = np.full(self.shape, self.mu, dtype=np.float64)

    def __call__(self) -> np.ndarray:
        self.state = (
            self.state
            + self.theta * (self.mu - self.state) * self.dt
            + self.sigma * np.sqrt(self.dt) * self.rng.standard_normal(self.shape)
        )
        return self.state.copy()

    def state_dict(self) -> dict[str, Any]:
        return {"state": self.state.tolist(), "rng": generator_state(self.rng)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.state = np.asarray(state["state"], dtype=np.float64).reshape(self.shape)
        set_generator_state(self.rng, state["rng"])


class GaussianNoise:
    """Independent N(0, sigma**2) noise every step."""

    def __init__(self, shape: tuple[int, ...], rng: np.random.Generator, sigma: float) -> None:
        self.shape = tuple(shape)
        self.rng = rng
        self.sigma = sigma

    def reset(self) -> None:
        """Nothing to reset; present so both noises share one interface."""

    def __call__(self) -> np.ndarray:
        return self.sigma * self.rng.standard_normal(self.shape)

    def state_dict(self) -> dict[str, Any]:
        return {"rng": generator_state(self.rng)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        set_generator_state(self.rng, state["rng"])


ActionNoise = OrnsteinUhlenbeckNoise | GaussianNoise


def make_noise(
    kind: str,
    shape: tuple[int, ...],
    rng: np.random.Generator,
    sigma: float,
    theta: float = 0.15,
    dt: float = 1e-2,
) -> ActionNoise:
    """``"ou"`` or ``"gaussian"`` noise drawing from ``rng``."""
    if kind == "ou":
        return OrnsteinUhlenbeckNoise(shape, rng, theta=theta, sigma=sigma, dt=dt)
    if kind == "gaussian":
        return GaussianNoise(shape, rng, sigma=sigma)
    raise ValueError(f"unknown noise {kind!r}; expected 'ou' or 'gaussian'")
