"""Save an episode of the intersection as an animated GIF."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from frl.envs import EnvConfig, IntersectionEnv
from frl.fileio import atomic_write

Policy = Callable[[np.ndarray], np.ndarray]


def record_episode(
    path: Path | str, task: str, seed: int, policy: Policy, config: EnvConfig | None = None
) -> Path:
    """Run one episode with ``policy`` and write its frames to ``path`` (GIF, atomically).

    ``config`` is the env's (its ``task`` is replaced by ``task``); default: ``EnvConfig()``.
    """
    from dataclasses import replace

    from PIL import Image

    path = Path(path)
    config = replace(config or EnvConfig(), task=task)
    env = IntersectionEnv(config, render_mode="rgb_array")
    try:
        observation, _ = env.reset(seed=seed)
        frames = [env.render()]
        done = False
        while not done:
            observation, _, terminated, truncated, _ = env.step(policy(observation))
            frames.append(env.render())
            done = terminated or truncated
        fps = env.metadata["render_fps"]
    finally:
        env.close()
    images = [Image.fromarray(frame) for frame in frames]
    with atomic_write(path) as f:
        images[0].save(
            f, format="GIF", save_all=True, append_images=images[1:], duration=1000 // fps, loop=0
        )
    return path
