"""Milliseconds per DDPG training step at the paper's sizes, sparse vs dense first layers.

One training step = ``act`` + ``observe`` + ``update`` (one gradient step, batch 256) on
the 26 x 18 x 3 grid observation with realistic scenes (a few vehicles plus the ego),
hidden [512, 512, 256, 64], after the buffer is filled past ``learning_starts``. Also
prints the replay buffer's memory for 100,000 grid transitions.

    python benchmarks/agent_speed.py [--steps 300] [--dense-steps 100] [--profile]
        [--option n_step=1 ...]

``--option KEY=VALUE`` sets a DDPGConfig field (repeatable), e.g. ``--option n_step=1``
for the paper's one-step targets against the default agent.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from cpu_settings import configure_cpu_training  # beside this script
from gymnasium import spaces

from frl.agents import DDPG, DDPGConfig, ReplayBuffer

GRID_SHAPE = (26, 18, 3)


class SyntheticScenes:
    """Grid observations shaped like the intersection's: 4-8 vehicles plus the ego.

    Each occupied cell holds [speed / 20, relative heading / 90 deg, 1]; cross traffic
    moves at +-90 degrees, a few vehicles share the ego's heading (heading 0, so only two
    non-zeros), and the ego fills its own cell.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def __call__(self) -> np.ndarray:
        grid = np.zeros(GRID_SHAPE, dtype=np.float32)
        n = self.rng.integers(4, 9)
        cells = self.rng.choice(GRID_SHAPE[0] * GRID_SHAPE[1], size=n, replace=False)
        for cell in cells:
            i, j = divmod(int(cell), GRID_SHAPE[1])
            grid[i, j] = (self.rng.uniform(0, 1), self.rng.choice([-1.0, 0.0, 1.0, 2.0]), 1.0)
        grid[13, 1] = (self.rng.uniform(0, 1), 0.0, 1.0)  # the ego
        return grid


def time_agent(
    sparse: bool, steps: int, warmup: int, profile: bool = False, options: dict | None = None
) -> tuple[float, float]:
    """Mean and best-block ms per act + observe + update, after ``learning_starts`` and
    ``warmup`` steps."""
    obs_space = spaces.Box(-2.0, 2.0, GRID_SHAPE, dtype=np.float32)
    act_space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
    config = DDPGConfig.from_dict(
        {**DDPGConfig().to_dict(), **(options or {}), "sparse_input": sparse}
    )
    agent = DDPG(obs_space, act_space, config, seed=0)
    scenes = SyntheticScenes(np.random.default_rng(1))
    rng = np.random.default_rng(2)
    obs = scenes()

    def step() -> None:
        nonlocal obs
        action = agent.act(obs, explore=True)
        next_obs = scenes()
        agent.observe(obs, action, float(rng.normal()), next_obs, bool(rng.random() < 0.02))
        agent.update()
        obs = next_obs

    for _ in range(agent.config.learning_starts + warmup):
        step()
    assert agent.num_updates >= warmup
    if profile:
        from torch.profiler import ProfilerActivity
        from torch.profiler import profile as torch_profile

        with torch_profile(activities=[ProfilerActivity.CPU]) as prof:
            for _ in range(50):
                step()
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=25))
    # Blocks of 25 steps: the mean is the figure; the best block shows the speed without
    # interference from other processes on a shared machine.
    blocks = []
    for _ in range(max(1, steps // 25)):
        start = time.perf_counter()
        for _ in range(25):
            step()
        blocks.append((time.perf_counter() - start) / 25 * 1e3)
    return float(np.mean(blocks)), float(np.min(blocks))


def buffer_megabytes(transitions: int = 100_000) -> tuple[float, int]:
    """Actual array bytes of a full 100k-transition grid buffer, and its row width."""
    config = DDPGConfig()
    buffer = ReplayBuffer(
        transitions,
        GRID_SHAPE,
        1,
        np.random.default_rng(0),
        sparse=True,
        sparse_width=config.sparse_capacity,
    )
    scenes = SyntheticScenes(np.random.default_rng(3))
    obs = scenes()
    for _ in range(transitions):
        next_obs = scenes()
        buffer.add(obs, np.zeros(1), 0.0, next_obs, False)
        obs = next_obs
    return buffer.nbytes / 1e6, buffer._obs.width


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--dense-steps", type=int, default=100)
    parser.add_argument("--warmup", type=int, default=50)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--skip-dense", action="store_true")
    parser.add_argument("--skip-buffer", action="store_true")
    parser.add_argument(
        "--option", action="append", default=[], metavar="KEY=VALUE", help="a DDPGConfig field"
    )
    args = parser.parse_args()
    options = {}
    for item in args.option:
        key, _, value = item.partition("=")
        if key not in DDPGConfig().to_dict() or not value:
            parser.error(f"--option {item!r}: expected KEY=VALUE with a DDPGConfig field")
        kind = type(DDPGConfig().to_dict()[key])
        options[key] = value.lower() in ("1", "true", "yes") if kind is bool else kind(value)

    threads = configure_cpu_training(args.threads)
    print(
        f"torch {torch.__version__}, {threads} threads, "
        f"obs {GRID_SHAPE}, hidden [512, 512, 256, 64]"
    )
    if options:
        print(f"options: {options}")
    sparse_ms, sparse_best = time_agent(True, args.steps, args.warmup, args.profile, options)
    print(
        f"sparse first layer : {sparse_ms:6.1f} ms/step mean, {sparse_best:5.1f} best block "
        "(act + observe + update, batch 256)"
    )
    if not args.skip_dense:
        dense_ms, dense_best = time_agent(False, args.dense_steps, args.warmup, options=options)
        print(
            f"dense first layer  : {dense_ms:6.1f} ms/step mean, {dense_best:5.1f} best block "
            "(same agent, sparse_input=False)"
        )
        print(f"speed-up           : {dense_ms / sparse_ms:6.2f}x")
    if not args.skip_buffer:
        megabytes, width = buffer_megabytes()
        dense_mb = 100_000 * 2 * np.prod(GRID_SHAPE) * 4 / 1e6
        print(
            f"replay buffer      : {megabytes:6.1f} MB for 100,000 grid transitions "
            f"(exact, {width} non-zeros/row; dense float32 would be {dense_mb:.0f} MB)"
        )


if __name__ == "__main__":
    main()
