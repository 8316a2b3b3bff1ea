"""The learning side of a fleet's round: what its agents cost on one device, SUMO left out.

    python benchmarks/fleet_learning.py [--vehicles 3,12,100] [--interval 300]
        [--device cpu] [--threads N] [--scenes PATH.npz] [--eager-too] [--stacked]

Builds ``N`` default agents (``agent=ddpg`` with the default budget's collision budget and
``train_freq`` = 8; learning from step 300, as ``fleet_scaling.py`` does) on ``--device``
in this one process, fills each one's buffer, then times one round of ``--interval``
steps: each vehicle in turn acts, stores the transition and updates when due, as the
vehicles one worker process hosts take turns in training. The scenes are replayed
(``agent_speed.py``'s, recorded from SUMO or loaded with ``--scenes``), so the time is what
the agents add to a round, not the round: the simulation's own steps (about 5-8 CPU ms per
vehicle step, ``benchmarks/collection.py``) come on top, spread over the cores.

On a GPU the agents' updates are captured as CUDA graphs (``DDPGConfig.cuda_graph``);
``--eager-too`` times the same fleet with every update eager beside them. ``--stacked``
times it another way: the vehicles step in lockstep, act in one batched forward pass and
learn in one stacked update (:mod:`frl.agents.stacked`, ``federation.stack_updates``),
captured as one graph on a GPU (and, with ``--eager-too``, eager beside it).

Prints per fleet and way: seconds per round, milliseconds per vehicle step, and the
device's peak memory (a GPU's ``max_memory_allocated``).
"""

from __future__ import annotations

import argparse
import sys
import time
from importlib.resources import files
from pathlib import Path

import numpy as np
import torch
from gymnasium import spaces
from omegaconf import OmegaConf

from frl.agents import DDPG, DDPGConfig
from frl.agents.learn import read_losses
from frl.agents.stacked import StackedUpdate
from frl.federation.workers import available_cores
from frl.train_config import ConfigError, check_device

sys.path.insert(0, str(Path(__file__).resolve().parent))
from agent_speed import GRID_SHAPE, RecordedScenes, default_agent_fields
from cpu_settings import configure_cpu_training

LEARNING_STARTS = 300


def fleet_config(cuda_graph: bool) -> DDPGConfig:
    """The training default's agent under the default budget (``budget=data``)."""
    budget = OmegaConf.to_container(OmegaConf.load(files("frl.conf") / "budget" / "data.yaml"))
    fields = {**default_agent_fields(), **budget["agent"]}
    return DDPGConfig(**{**fields, "learning_starts": LEARNING_STARTS, "cuda_graph": cuda_graph})


class Vehicle:
    """One agent replaying the scenes from its own starting point."""

    def __init__(self, index: int, config: DDPGConfig, scenes: RecordedScenes, device: str):
        grid = spaces.Box(-2.0, 2.0, GRID_SHAPE, dtype=np.float32)
        accel = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
        self.agent = DDPG(grid, accel, config, seed=index, device=device)
        self.scenes, self.position = scenes, (index * 97) % len(scenes.observations)
        self.obs = self.scenes.observations[self.position]
        self.pending: list[dict] = []

    def step(self, update: bool = True, policy_action: np.ndarray | None = None) -> None:
        """Act (on ``policy_action`` where the policy's action is given), observe and
        (``update``) update when due."""
        scenes, agent = self.scenes, self.agent
        action = agent.act(self.obs, explore=True, policy_action=policy_action)
        self.position = (self.position + 1) % len(scenes.observations)
        next_obs = scenes.observations[self.position]
        terminated = bool(scenes.terminated[self.position])
        cost = float(terminated and self.position % 3 == 0)  # some episodes end in a crash
        agent.observe(self.obs, action, float(scenes.rewards[self.position]), next_obs,
                      terminated, cost=cost)  # fmt: skip
        losses = agent.update_unread() if update else {}
        if losses:
            self.pending.append(losses)  # read at the round's end, as training does
        self.obs = next_obs
        if terminated:
            agent.episode_start()


def time_round(
    vehicles: list[Vehicle], interval: int, device: torch.device,
    stacked: StackedUpdate | None = None,
) -> float:  # fmt: skip
    """Seconds for every vehicle to take ``interval`` steps, in turns (or with
    ``stacked``, in lockstep: acting in one batched forward pass, learning in the one
    stacked update after each step)."""
    began = time.perf_counter()
    for _ in range(interval):
        if stacked is None:
            for vehicle in vehicles:
                vehicle.step()
        else:
            actions = stacked.policy_actions([vehicle.obs for vehicle in vehicles])
            for vehicle, action in zip(vehicles, actions, strict=True):
                vehicle.step(update=False, policy_action=action)
            for vehicle, losses in zip(vehicles, stacked.update_unread(), strict=True):
                if losses:
                    vehicle.pending.append(losses)
    for vehicle in vehicles:
        read_losses(vehicle.pending)
        vehicle.pending.clear()
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return time.perf_counter() - began


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", default="3,12,100")
    parser.add_argument("--interval", type=int, default=300)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--scenes", type=Path, default=None)
    parser.add_argument("--eager-too", action="store_true")
    parser.add_argument("--stacked", action="store_true")
    args = parser.parse_args()
    try:
        device = torch.device(check_device(args.device))
    except ConfigError as error:
        parser.error(str(error))
    try:
        fleets = [int(n) for n in args.vehicles.split(",")]
    except ValueError:
        parser.error(f"--vehicles {args.vehicles!r}: a comma-separated list of counts")
    if min(fleets) < 1 or args.interval < 1:
        parser.error("--vehicles and --interval must be positive")
    if args.threads is not None and not 0 < args.threads <= available_cores():
        parser.error(f"--threads {args.threads}: 1 to {available_cores()} on this machine")
    if args.scenes is not None and not args.scenes.is_file():
        parser.error(f"--scenes {args.scenes}: no such file")
    threads = configure_cpu_training(args.threads)
    scenes = RecordedScenes.record() if args.scenes is None else RecordedScenes.load(args.scenes)
    on_gpu = device.type == "cuda"
    ways = ["captured", "eager"] if on_gpu and args.eager_too else ["captured"]
    if args.stacked:
        ways += ["stacked", "stacked eager"] if on_gpu and args.eager_too else ["stacked"]
    print(f"torch {torch.__version__}, device {device}, {threads} threads; "
          f"a round of {args.interval} steps per vehicle, an update every 8")  # fmt: skip
    print("| vehicles | updates | s per round | ms per vehicle step | peak device memory |")
    print("|---|---|---|---|---|")
    for count in fleets:
        for way in ways:
            config = fleet_config(cuda_graph=way in ("captured", "stacked"))
            vehicles = [Vehicle(i, config, scenes, str(device)) for i in range(count)]
            stacked = (
                StackedUpdate([v.agent for v in vehicles]) if way.startswith("stacked") else None
            )
            time_round(vehicles, LEARNING_STARTS + 40, device, stacked)  # fill, warm up
            if device.type == "cuda":
                torch.cuda.reset_peak_memory_stats(device)
            seconds = time_round(vehicles, args.interval, device, stacked)
            if way == "captured":
                way = "CUDA graph" if on_gpu else "one by one"
            elif way == "stacked" and on_gpu:
                way = "stacked, one CUDA graph"
            memory = (
                f"{torch.cuda.max_memory_allocated(device) / 2**30:.2f} GiB"
                if device.type == "cuda"
                else "-"
            )
            per_step = 1e3 * seconds / (count * args.interval)
            print(f"| {count} | {way} | {seconds:.1f} | {per_step:.2f} | {memory} |", flush=True)
            del vehicles, stacked
            if device.type == "cuda":
                torch.cuda.empty_cache()


if __name__ == "__main__":
    main()
