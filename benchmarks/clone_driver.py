"""The cloned driver: frl's actor fitted to the gap-acceptance rule's actions alone.

    python benchmarks/clone_driver.py [--seeds 0,1,2,3,4] [--agent ddpg] \\
        [--teacher gap_acceptance] [--steps-per-task 10000] [--updates 9000] \\
        [--out docs/results/data/study-driver]

For each run seed, the rule drives each task for ``--steps-per-task`` steps (the paper's
budget per vehicle) on the training traffic of that seed's vehicles (the same SUMO seeds
as FedAvg-DDPG's vehicle for that task), perturbed as DART does so that the states after
a mistake are seen too: at a decision, with chance 5%, a uniform random action is held for
10 steps. Every visited observation is labelled with the rule's action. The actor of the
``--agent`` preset (frl's default: the vehicles encoder, [512, 512, 256, 64], a clipped
output) is then fitted by mean squared error to the labels, the three tasks' grids pooled
as FedAvg's one model serves them all: ``--updates`` Adam steps at batch 256 (as many
gradient steps as a vehicle takes in a 10,000-step run), learning rate 3e-4. No reward is
used. The clone drives the run seed's test episodes beside full throttle, the rule and the
oracle (:func:`frl.evaluate.evaluate_policy`), and ``OUT/clone-seed{seed}/results.json``
keeps its table: the row that says what a guided agent adds beyond its teacher.

``--teacher committed_gap_acceptance`` clones the committed rule instead (a teacher of
``frl.policies.TEACHERS``): it reads the distance to the stop line from the route
observation, so it drives, labels and is tested on observations with the route beside
the grid (``env.route_observation``), as the guided agent with that teacher sees them.
"""

from __future__ import annotations

import argparse
import sys
import time
from importlib.resources import files
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from omegaconf import OmegaConf

from frl.agents import DDPG, DDPGConfig, SparseRows
from frl.envs import TASKS, EnvConfig, IntersectionEnv
from frl.evaluate import evaluate_policy
from frl.federation.client import training_sumo_seed
from frl.federation.plan import client_seeds
from frl.fileio import write_json_atomic
from frl.policies import TEACHERS, TEACHERS_READING_THE_ROUTE
from frl.provenance import versions

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cpu_settings import configure_cpu_training

PERTURB_PROBABILITY = 0.05
"""Chance per decision that a perturbation starts (DART-style noise injection)."""
PERTURB_STEPS = 10
"""Steps a perturbation's uniform random action is held."""
BATCH_SIZE = 256
LEARNING_RATE = 3e-4


def agent_config(preset: str) -> DDPGConfig:
    """The DDPGConfig of an ``agent=`` preset (``frl/conf/agent/<preset>.yaml``)."""
    path = files("frl.conf") / "agent" / f"{preset}.yaml"
    fields = dict(DDPGConfig().to_dict())
    for layer in _preset_layers(path):
        fields.update(layer)
    return DDPGConfig.from_dict(fields)


def _preset_layers(path) -> list[dict]:  # type: ignore[no-untyped-def]
    """A preset and the presets it builds on (Hydra defaults), base first."""
    data = OmegaConf.to_container(OmegaConf.load(path))
    layers = []
    for entry in data.pop("defaults", []):
        if isinstance(entry, str) and entry != "_self_":
            layers += _preset_layers(path.parent / f"{entry}.yaml")
    data.pop("name", None)
    return [*layers, data]


def collect(
    seed: int, steps_per_task: int, teacher: str = "gap_acceptance"
) -> tuple[list[Any], np.ndarray]:
    """The teacher's perturbed driving on each task: observations and its labels. A
    teacher that reads the route (``committed_gap_acceptance``) drives, and labels,
    observations with the route beside the grid."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xC10E]))
    observations: list[Any] = []
    labels: list[float] = []
    route = teacher in TEACHERS_READING_THE_ROUTE
    for task, (_, env_seed) in zip(TASKS, client_seeds(seed, len(TASKS)), strict=True):
        env = IntersectionEnv(EnvConfig(task=task, route_observation=route))
        rule = TEACHERS[teacher](env.config)
        try:
            restarts = 0
            obs, _ = env.reset(seed=training_sumo_seed(env_seed, restarts))
            held, held_left = None, 0
            for _ in range(steps_per_task):
                label = rule(obs)
                observations.append(obs)
                labels.append(float(label[0]))
                if held_left == 0 and rng.random() < PERTURB_PROBABILITY:
                    held = np.array([rng.uniform(-1.0, 1.0)], np.float32)
                    held_left = PERTURB_STEPS
                action = held if held_left > 0 else label
                held_left = max(0, held_left - 1)
                obs, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    obs, _ = env.reset()  # a new ego in the traffic that kept flowing
                    held_left = 0
        finally:
            env.close()
    return observations, np.asarray(labels, np.float32)


def fit(
    observations: list[Any], labels: np.ndarray, config: DDPGConfig, seed: int, updates: int,
    route_observation: bool = False,
) -> tuple[DDPG, float]:  # fmt: skip
    """The preset's actor fitted to the labels; the agent and the last batch's loss."""
    env = IntersectionEnv(EnvConfig(route_observation=route_observation))
    agent_seed = client_seeds(seed, len(TASKS))[0][0]
    agent = DDPG(env.observation_space, env.action_space, config, seed=agent_seed)
    env.close()
    rows = torch.from_numpy(np.stack([agent.layout.flat(o) for o in observations]))
    targets = torch.from_numpy(labels)
    optimizer = torch.optim.Adam(agent.actor.parameters(), lr=LEARNING_RATE)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xF17]))
    loss = torch.zeros(())
    for _ in range(updates):
        index = torch.from_numpy(rng.integers(0, len(targets), BATCH_SIZE))
        batch = rows[index]
        inputs = SparseRows.from_dense(batch) if agent.sparse else batch
        with agent._autocast():
            prediction = agent.actor.preactivation(inputs).squeeze(-1)
        loss = F.mse_loss(prediction.float(), targets[index])
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    return agent, loss.item()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--agent", default="ddpg", help="the agent= preset whose actor is fitted")
    parser.add_argument("--teacher", default="gap_acceptance", help=f"one of {', '.join(TEACHERS)}")
    parser.add_argument("--steps-per-task", type=int, default=10_000)
    parser.add_argument("--updates", type=int, default=9_000)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("runs/clone"))
    args = parser.parse_args()
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
        config = agent_config(args.agent)
    except (ValueError, FileNotFoundError, OSError) as error:
        parser.error(str(error))
    if min(seeds) < 0 or args.steps_per_task <= 0 or args.updates <= 0 or args.episodes <= 0:
        parser.error("seeds must be >= 0; --steps-per-task, --updates and --episodes > 0")
    if args.teacher not in TEACHERS:
        parser.error(f"--teacher {args.teacher!r}: choose one of {', '.join(TEACHERS)}")
    route = args.teacher in TEACHERS_READING_THE_ROUTE
    threads = configure_cpu_training()
    for seed in seeds:
        started = time.perf_counter()
        observations, labels = collect(seed, args.steps_per_task, args.teacher)
        collected = time.perf_counter()
        agent, loss = fit(observations, labels, config, seed, args.updates, route)
        fitted = time.perf_counter()
        table = evaluate_policy(agent, seed=seed, episodes=args.episodes, route_observation=route)
        results = {
            "scheme": "clone",
            "seed": seed,
            "clone": {
                "agent": args.agent,
                "teacher": args.teacher,
                "agent_config": config.to_dict(),
                "steps_per_task": args.steps_per_task,
                "perturbation": {"probability": PERTURB_PROBABILITY, "steps": PERTURB_STEPS},
                "updates": args.updates,
                "batch_size": BATCH_SIZE,
                "learning_rate": LEARNING_RATE,
                "rule_brakes_share": float(np.mean(labels < 0)),
                "final_loss": loss,
                "collect_s": collected - started,
                "fit_s": fitted - collected,
                "threads": threads,
            },
            "evaluation": table,
            "versions": versions(),
        }
        write_json_atomic(args.out / f"clone-seed{seed}" / "results.json", results)
        average = table["average"]
        print(
            f"clone seed {seed}: {average['average_reward']:.2f}, "
            f"{average['collision_rate']:.1%} collisions, {average['arrival_rate']:.1%} arrivals "
            f"(collect {collected - started:.0f} s, fit {fitted - collected:.0f} s, "
            f"loss {loss:.3f})",
            flush=True,
        )


if __name__ == "__main__":
    main()
