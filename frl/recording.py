"""Save an episode of the intersection as an animated GIF."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from frl.envs import IntersectionEnv
from frl.fileio import atomic_write

Policy = Callable[[np.ndarray], np.ndarray]


def record_episode(path: Path | str, task: str, seed: int, policy: Policy) -> Path:
    """Run one episode with ``policy`` and write its frames to ``path`` (GIF, atomically)."""
    from PIL import Image

    path = Path(path)
    env = IntersectionEnv(task=task, render_mode="rgb_array")
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
