"""Save episodes of the intersection as animated GIFs: one driver, or several side by side."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from frl.envs import EnvConfig, IntersectionEnv
from frl.fileio import atomic_write

Policy = Callable[[Any], np.ndarray]


@dataclass(frozen=True)
class Driver:
    """A policy to film, under a caption. ``make`` builds it for the episode's env (a
    yardstick may read the env, as the committed rule and the oracle do); ``on_reset`` is
    called after the reset (an agent's ``episode_start``)."""

    label: str
    make: Callable[[IntersectionEnv], Policy]
    on_reset: Callable[[], None] | None = None


def film_episode(
    driver: Driver, task: str, seed: int, config: EnvConfig | None = None
) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Drive one seeded episode of ``task`` and return its frames (the caption drawn in)
    and the last step's ``info``. ``config`` is the env's (its task replaced)."""
    config = replace(config or EnvConfig(), task=task)
    env = IntersectionEnv(config, render_mode="rgb_array")
    try:
        policy = driver.make(env)
        observation, info = env.reset(seed=seed)
        if driver.on_reset is not None:
            driver.on_reset()
        frames = [env.render()]
        done = False
        while not done:
            observation, _, terminated, truncated, info = env.step(policy(observation))
            frames.append(env.render())
            done = terminated or truncated
    finally:
        env.close()
    outcome = "collided" if info["collision"] else "arrived" if info["arrived"] else "timed out"
    caption = f"{driver.label}: {outcome} at step {info['travel_time_steps']}"
    return [_captioned(frame, caption) for frame in frames], info


def write_gif(path: Path | str, frames: Sequence[np.ndarray], fps: int) -> Path:
    """``frames`` as a looping GIF at ``fps``, written atomically."""
    from PIL import Image

    path = Path(path)
    images = [Image.fromarray(frame) for frame in frames]
    with atomic_write(path) as f:
        images[0].save(
            f, format="GIF", save_all=True, append_images=images[1:], duration=1000 // fps, loop=0
        )
    return path


def side_by_side(*films: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Films joined left to right, frame by frame; one that ends first holds its last frame."""
    length = max(len(film) for film in films)
    return [
        np.concatenate([film[min(i, len(film) - 1)] for film in films], axis=1)
        for i in range(length)
    ]


def record_episode(
    path: Path | str, task: str, seed: int, policy: Policy, config: EnvConfig | None = None
) -> Path:
    """Run one episode with ``policy`` and write its frames to ``path`` (GIF, atomically).

    ``config`` is the env's (its ``task`` is replaced by ``task``); default: ``EnvConfig()``.
    """
    config = config or EnvConfig()
    frames, _ = film_episode(Driver("policy", lambda env: policy), task, seed, config)
    return write_gif(path, frames, fps=round(1 / config.scenario.step_length))


def _captioned(frame: np.ndarray, caption: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    image = Image.fromarray(frame)
    draw = ImageDraw.Draw(image)
    draw.rectangle((0, 0, image.width, 16), fill=(0, 0, 0))
    draw.text((4, 2), caption, fill=(255, 255, 255))
    return np.asarray(image)
