"""CPU milliseconds of one training environment step, split into its parts, per precision.

    python benchmarks/collection.py [--steps 6000] [--precisions float32,bf16] [--threads 1]

A training step in which no update is due is what collecting data costs. This drives the
vehicle's own loop (``VehicleClient.train``, what the main command runs) with frl's
default agent (``agent=ddpg``) going straight in default traffic, the policy acting from
the first step (no uniform warm-up) and no update ever due, and times each part on the
process's CPU clock:

- ``sumo``: the simulation step and reading the vehicles back (libsumo, in-process);
- ``observation``: the occupancy grid built from those vehicles;
- ``forward``: the actor's forward pass, with what turns its output into an action;
- ``noise``: the exploration noise;
- ``buffer``: the replay buffer's write;
- ``rest``: everything else (reward, n-step accumulation, the loop's records, episode
  ends and SUMO's resets).

Beside it, two references on the same machine: ``predict`` alone, ``DDPG.predict`` on one
recorded grid at a time, and SUMO alone, the environment stepped with a fixed action
(simulation, observation and reward, resets included). Each precision is a fresh agent in
this process; bf16 where the CPU lacks it natively is emulated (the table says so), and
acting runs in float32 whatever the precision (frl.agents.acting).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from frl.agents import DDPGConfig
from frl.agents.precision import has_native_bf16
from frl.envs import EnvConfig, IntersectionEnv, RewardConfig
from frl.federation.client import ClientSpec, VehicleClient

sys.path.insert(0, str(Path(__file__).resolve().parent))
from agent_speed import default_agent_fields
from cpu_settings import configure_cpu_training

PARTS = ("sumo", "observation", "forward", "noise", "buffer", "rest")


class CpuClock:
    """CPU seconds spent inside wrapped callables, by label."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    def wrap(self, label: str, function: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            start = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                self.seconds[label] += time.process_time() - start

        return timed


class TimedNoise:
    """The agent's noise process, its draws timed (``__call__`` is looked up on the type,
    so the instance cannot simply be patched)."""

    def __init__(self, noise: Any, clock: CpuClock) -> None:
        self._noise = noise
        self._draw = clock.wrap("noise", noise.__call__)

    def __call__(self) -> np.ndarray:
        return self._draw()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._noise, name)


def default_agent(precision: str) -> DDPGConfig:
    """``agent=ddpg`` (its preset file) at ``precision``, acting from the first step with
    no update ever due."""
    fields = {**default_agent_fields(), "precision": precision}
    return DDPGConfig.from_dict({**fields, "learning_starts": 0, "train_freq": 10**9})


def training_step_parts(precision: str, steps: int) -> dict[str, float]:
    """Milliseconds of CPU per step by part, and ``total``."""
    spec = ClientSpec(
        index=0,
        task="straight",
        env=EnvConfig(),
        reward=RewardConfig(),
        agent=default_agent(precision),
        agent_seed=0,
        env_seed=0,
    )
    client = VehicleClient(spec)
    try:
        client.train(200, upload=False)  # SUMO started, buffers and caches warm
        clock = CpuClock()
        env, agent = client.env, client.agent
        env._advance = clock.wrap("sumo", env._advance)
        env._simulation.vehicles = clock.wrap("sumo", env._simulation.vehicles)
        env._grid = clock.wrap("observation", env._grid)
        agent.act = clock.wrap("acting", agent.act)
        agent.explorer.noise = TimedNoise(agent.explorer.noise, clock)
        agent.buffer.add = clock.wrap("buffer", agent.buffer.add)
        start = time.process_time()
        client.train(steps, upload=False)
        total = time.process_time() - start
    finally:
        client.close()
    seconds = dict(clock.seconds)
    seconds["forward"] = seconds.pop("acting") - seconds["noise"]
    seconds["rest"] = total - sum(seconds.values())
    seconds["total"] = total
    return {part: 1e3 * value / steps for part, value in seconds.items()}


def recorded_grids(steps: int) -> list[np.ndarray]:
    """Grids the ego meets going straight with held random accelerations."""
    rng = np.random.default_rng(0)
    env = IntersectionEnv(task="straight")
    grids = []
    try:
        obs, _ = env.reset(seed=0)
        action = np.zeros(1, np.float32)
        for _ in range(steps):
            if rng.random() < 1 / 20:
                action = rng.uniform(-1, 1, size=1).astype(np.float32)
            grids.append(obs)
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                obs, _ = env.reset()
    finally:
        env.close()
    return grids


def predict_ms(precision: str, grids: list[np.ndarray]) -> float:
    """CPU milliseconds of ``DDPG.predict`` on one grid."""
    from frl.agents import DDPG

    env = IntersectionEnv(task="straight")
    agent = DDPG(env.observation_space, env.action_space, default_agent(precision), seed=0)
    env.close()
    for grid in grids[:100]:
        agent.predict(grid)
    start = time.process_time()
    for grid in grids:
        agent.predict(grid)
    return 1e3 * (time.process_time() - start) / len(grids)


def sumo_alone_ms(steps: int) -> float:
    """CPU milliseconds of one environment step with a fixed action, resets included."""
    env = IntersectionEnv(task="straight")
    action = np.full(1, 0.3, np.float32)
    try:
        env.reset(seed=0)
        start = time.process_time()
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        return 1e3 * (time.process_time() - start) / steps
    finally:
        env.close()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=6000, help="timed steps per precision")
    parser.add_argument("--precisions", default="float32,bf16")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args(argv)
    if args.steps <= 0:
        parser.error(f"--steps must be positive, got {args.steps}")
    precisions = [p for p in args.precisions.split(",") if p]
    unknown = sorted(set(precisions) - {"float32", "bf16"})
    if unknown:
        parser.error(f"--precisions takes float32 and bf16, got {', '.join(unknown)}")
    threads = configure_cpu_training(args.threads)
    native = "native" if has_native_bf16("cpu") else "emulated"
    print(f"CPU ms per training environment step, {args.steps} steps, {threads} torch thread(s)")
    print(f"| precision | {' | '.join(PARTS)} | total | predict alone |")
    print(f"|---|{'---|' * (len(PARTS) + 2)}")
    grids = recorded_grids(min(args.steps, 3000))
    for precision in precisions:
        parts = training_step_parts(precision, args.steps)
        label = precision if precision == "float32" else f"{precision} ({native})"
        cells = " | ".join(f"{parts[part]:.3f}" for part in PARTS)
        print(
            f"| {label} | {cells} | **{parts['total']:.3f}** | {predict_ms(precision, grids):.3f} |"
        )
    print(f"SUMO alone (simulation, observation, reward): {sumo_alone_ms(args.steps):.3f} ms")


if __name__ == "__main__":
    main()
