"""Whether a run's collisions can be foreseen on the approach: by its cost critic, and by
networks fitted afterwards on far more of the car's own driving.

    python scripts/cost_separability.py RUN_DIR [--episodes 2000] [--tasks left,straight]
        [--cache DIR] [--shares 10,2,1] [--head] [--exploring] [--pooled]

Drives the run's model without noise (as it is tested) on ``--episodes`` episodes per
task from fixed SUMO seeds (70,000 on), and keeps every state of the approach (from 30 m
before the stop line to 15 m past it) with the action taken and whether its episode
collided. A fifth of the episodes is held out; on their states more than ``--lead``
seconds before the episode's end it prints, before the line and past it, how well each
of these ranks the states of episodes that collided above the others (ROC AUC: 0.5 is
blind, 1 tells them apart):

- **the run's cost critic**, Q_c(s, a);
- **a fresh critic**: the run's critic architecture (vehicles encoder and trunk), newly
  initialised and fitted by logistic loss to the same label, half of each batch from
  collided episodes, on a tenth, a half and all of the other episodes (``--shares``; a
  tenth is about what a vehicle drives in a round);
- ``--head``: the cost head's architecture fitted the same way on all of them, reading
  the run's own reward critic's last hidden layer, frozen, as the default's head does;
- ``--exploring``: the fresh critic and the head fitted instead on as many episodes driven
  by the exploring car (the policy plus the run's OU noise, as training drives), judged
  on the same noise-free held-out states;
- ``--pooled``: a fresh critic fitted on half of each task's episodes together (the
  paper's grid does not show the task), judged on each task.

``--cache DIR`` keeps the driven states (NumPy archives) so that a second call only fits.
"""

from __future__ import annotations

import argparse
import io
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from frl import run_directory as rundir
from frl.agents import DDPG, SparseRows
from frl.agents.networks import CostHead, Critic, build_cost_head, build_network
from frl.envs import IntersectionEnv
from frl.evaluate import run_settings
from frl.federation.assembly import evaluation_env
from frl.fileio import write_bytes_atomic
from frl.policies import load_model

APPROACH_M = (-15.0, 30.0)
"""The stop-line distances (m; negative: past the line) whose states are kept."""
SEED_BASE = 70_000
"""Noise-free episodes' SUMO seeds start here, the exploring car's 10,000 above: fixed
seeds, not the run's test seeds (odd seeds drawn from a range of 2**31)."""
EXPLORING_SEED_OFFSET = 10_000
FIT_LR = 3e-4

Data = dict[str, np.ndarray]


def drive(agent: DDPG, env: IntersectionEnv, seeds: range, exploring: bool) -> Data:
    """The approach states of ``seeds`` driven by the model, with its noise where
    ``exploring``: observations, actions, each one's episode, the steps left to its end,
    the distance to the stop line and whether the episode collided."""
    columns: dict[str, list[Any]] = {
        key: [] for key in ("obs", "actions", "episode", "steps_left", "collided", "distance")
    }
    for episode, seed in enumerate(seeds):
        observation, _ = env.reset(seed=seed)
        agent.explorer.episode_start()
        kept: list[int] = []
        step = 0
        while True:
            flat = np.asarray(agent.layout.flat(observation), np.float32).reshape(-1)
            # the policy's own action in [-1, 1], to which the explorer adds its noise
            unit = agent._policy_action(flat)
            action = agent.scale.from_unit(agent.explorer.noisy(unit) if exploring else unit)
            distance = env.stop_line_distance_m
            if APPROACH_M[0] < distance <= APPROACH_M[1]:
                columns["obs"].append(flat.astype(np.float16))  # half of float32's memory
                columns["actions"].append(np.asarray(action, np.float32).reshape(-1))
                columns["distance"].append(distance)
                kept.append(step)
            observation, _, terminated, truncated, info = env.step(action)
            step += 1
            if terminated or truncated:
                break
        columns["episode"] += [episode] * len(kept)
        columns["steps_left"] += [step - k for k in kept]
        columns["collided"] += [bool(info["collision"])] * len(kept)
    return {key: np.stack(values) if key in ("obs", "actions") else np.array(values)
            for key, values in columns.items()}  # fmt: skip


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """The probability that a positive's score exceeds a negative's (ties count half);
    NaN where either class is missing."""
    positives = int(labels.sum())
    negatives = len(labels) - positives
    if positives == 0 or negatives == 0:
        return float("nan")
    order = np.argsort(scores, kind="stable")
    _, first, counts = np.unique(scores[order], return_index=True, return_counts=True)
    ranks = np.empty(len(scores))
    ranks[order] = np.repeat(first + (counts + 1) / 2.0, counts)  # tied scores share a rank
    return float((ranks[labels].sum() - positives * (positives + 1) / 2) / (positives * negatives))


def as_input(agent: DDPG, obs: np.ndarray) -> torch.Tensor | SparseRows:
    x = torch.from_numpy(obs.astype(np.float32))
    return SparseRows.from_dense(x) if agent.sparse else x


def unit_actions(agent: DDPG, data: Data) -> torch.Tensor:
    return torch.from_numpy(agent.scale.to_unit(data["actions"], batch=True).astype(np.float32))


def reward_critic_hidden(agent: DDPG, data: Data, rows: np.ndarray) -> torch.Tensor:
    """The run's reward critic's last hidden layer on ``rows``: what its cost head reads."""
    actions, parts = unit_actions(agent, data), []
    with torch.no_grad():
        for start in range(0, len(rows), 4096):
            part = rows[start : start + 4096]
            obs = as_input(agent, data["obs"][part])
            parts.append(agent.networks.critic.values_and_hidden(obs, actions[part])[1])
    return torch.cat(parts)


class Scorer:
    """A network fitted to tell collided episodes' states apart: a fresh critic on
    (observation, action), or a cost head on the run's frozen reward-critic features."""

    def __init__(self, agent: DDPG, head: bool, seed: int = 1) -> None:
        generator = torch.Generator().manual_seed(seed)
        cpu = torch.device("cpu")
        self.agent, self.head = agent, head
        self.network: Critic | CostHead = (
            build_cost_head(agent.config, generator, cpu) if head else build_network(
                Critic, agent.obs_dim, agent.action_dim, agent.config, agent.layout,
                generator, cpu,
            )
        )  # fmt: skip
        self.rng = np.random.default_rng(seed)

    def inputs(self, data: Data, rows: np.ndarray) -> torch.Tensor:
        """What the network reads for ``rows``: the frozen features for a head, else the
        actions in [-1, 1] (the observations are read batch by batch)."""
        if self.head:
            return reward_critic_hidden(self.agent, data, rows)
        return unit_actions(self.agent, data)[rows]

    def logits(self, data: Data, rows: np.ndarray, inputs: torch.Tensor) -> torch.Tensor:
        """The network on ``rows``, whose :meth:`inputs` are ``inputs``."""
        if self.head:
            return self.network(inputs)
        return self.network(as_input(self.agent, data["obs"][rows]), inputs)

    def fit(self, data: Data, rows: np.ndarray, updates: int) -> Scorer:
        """Logistic loss on ``rows``, half of each batch of 256 from collided episodes."""
        inputs = self.inputs(data, rows)
        labels = torch.from_numpy(data["collided"][rows].astype(np.float32))
        collided = np.flatnonzero(data["collided"][rows])
        others = np.flatnonzero(~data["collided"][rows])
        optimizer = torch.optim.Adam(self.network.parameters(), lr=FIT_LR)
        for _ in range(updates):
            batch = np.concatenate([self.rng.choice(collided, 128), self.rng.choice(others, 128)])
            logits = self.logits(data, rows[batch], inputs[batch])
            loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, labels[batch])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        return self

    def scores(self, data: Data, rows: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            inputs = self.inputs(data, rows)
            parts = [
                self.logits(data, rows[s : s + 4096], inputs[s : s + 4096])
                for s in range(0, len(rows), 4096)
            ]
        return torch.cat(parts).numpy()


def stage_aucs(scores: np.ndarray, data: Data, test: np.ndarray) -> str:
    """AUC on the held-out states before the stop line and on those past it."""
    labels = data["collided"][test]
    before = data["distance"][test] > 0
    return ", ".join(
        f"{name} {roc_auc(scores[rows], labels[rows]):.3f}"
        for name, rows in (("before the line", before), ("past it", ~before))
    )


def both_kinds(data: Data, rows: np.ndarray) -> bool:
    return bool(data["collided"][rows].any() and not data["collided"][rows].all())


def driven(
    agent: DDPG, env: IntersectionEnv, seeds: range, exploring: bool, cache: Path | None
) -> Data:
    """:func:`drive`'s states, read from ``cache`` where it holds them, else kept there."""
    if cache is not None and cache.exists():
        with np.load(cache) as stored:
            return dict(stored)
    data = drive(agent, env, seeds, exploring)
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        archive = io.BytesIO()
        np.savez(archive, **data)
        write_bytes_atomic(cache, archive.getvalue())
    return data


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--tasks", default="left,straight")
    parser.add_argument("--lead", type=float, default=1.0, help="seconds before the end")
    parser.add_argument("--updates", type=int, default=4000)
    parser.add_argument("--cache", type=Path, default=None, help="keep the driven states here")
    parser.add_argument(
        "--shares", default="10,2,1", help="fresh critics on 1/k of the episodes, for each k"
    )
    parser.add_argument("--head", action="store_true")
    parser.add_argument("--exploring", action="store_true")
    parser.add_argument("--pooled", action="store_true")
    args = parser.parse_args()
    settings = run_settings(args.run_dir)
    files = rundir.model_files(args.run_dir)
    tasks = args.tasks.split(",")
    try:
        shares = [int(k) for k in args.shares.split(",") if k]
    except ValueError:
        shares = []
    if not shares or min(shares) < 1:
        parser.error(f"--shares: whole numbers of at least 1, got {args.shares!r}")
    unknown = sorted(set(tasks) - set(files))
    if unknown:
        parser.error(f"--tasks: {', '.join(unknown)}: the run has models for {', '.join(files)}")
    torch.manual_seed(0)
    step_s = settings.env.scenario.step_length
    held_out: dict[str, tuple[DDPG, Data, np.ndarray, np.ndarray]] = {}
    for task in tasks:
        env = IntersectionEnv(replace(evaluation_env(settings, task), task=task))
        try:
            agent = load_model(files[task][0], env)
            seeds = range(SEED_BASE, SEED_BASE + args.episodes)
            cache = args.cache / f"{task}-{args.episodes}.npz" if args.cache else None
            data = driven(agent, env, seeds, False, cache)
            train = np.flatnonzero(data["episode"] % 5 != 0)
            exploring = None
            if args.exploring:
                start = SEED_BASE + EXPLORING_SEED_OFFSET
                count = len(np.unique(data["episode"][train]))
                cache = args.cache / f"{task}-exploring-{count}.npz" if args.cache else None
                exploring = driven(agent, env, range(start, start + count), True, cache)
        finally:
            env.close()
        test = np.flatnonzero(
            (data["episode"] % 5 == 0) & (data["steps_left"] * step_s > args.lead)
        )
        held_out[task] = (agent, data, train, test)
        collided = len(np.unique(data["episode"][data["collided"]]))
        print(
            f"{task}: {args.episodes} noise-free episodes, {collided} collided; "
            f"{len(test)} held-out states more than {args.lead:.1f} s before the end "
            f"({int(data['collided'][test].sum())} of collided episodes). AUC:"
        )
        own = agent.critic_values(
            data["obs"][test].astype(np.float32), data["actions"][test], cost=True
        )
        print(f"  the run's cost critic: {stage_aucs(own, data, test)}")
        episodes = np.unique(data["episode"][train])
        for share in shares:
            rows = train[np.isin(data["episode"][train], episodes[: len(episodes) // share])]
            name = f"a fresh critic on {len(episodes) // share} episodes"
            if not both_kinds(data, rows):
                print(f"  {name}: not both kinds of episode to fit on")
                continue
            scorer = Scorer(agent, head=False).fit(data, rows, args.updates)
            print(f"  {name}: {stage_aucs(scorer.scores(data, test), data, test)}")
        if args.head and both_kinds(data, train):
            scorer = Scorer(agent, head=True).fit(data, train, args.updates)
            print(
                "  a head on the run's frozen critic features: "
                + stage_aucs(scorer.scores(data, test), data, test)
            )
        if exploring is not None and both_kinds(exploring, np.arange(len(exploring["obs"]))):
            crashes = len(np.unique(exploring["episode"][exploring["collided"]]))
            everything = np.arange(len(exploring["obs"]))
            for head in (False, True):
                name = "a head on the frozen features" if head else "a fresh critic"
                scorer = Scorer(agent, head).fit(exploring, everything, args.updates)
                print(
                    f"  {name}, fitted on the exploring car ({crashes} of {len(episodes)} "
                    f"collided): {stage_aucs(scorer.scores(data, test), data, test)}"
                )
    if args.pooled and len(held_out) > 1:
        pooled = {key: [] for key in ("obs", "actions", "collided")}
        for _, data, train, _ in held_out.values():
            episodes = np.unique(data["episode"][train])
            rows = train[np.isin(data["episode"][train], episodes[: len(episodes) // 2])]
            for key in pooled:
                pooled[key].append(data[key][rows])
        together = {key: np.concatenate(parts) for key, parts in pooled.items()}
        first_agent = next(iter(held_out.values()))[0]
        scorer = Scorer(first_agent, head=False).fit(
            together, np.arange(len(together["obs"])), args.updates
        )
        for task, (agent, data, _, test) in held_out.items():
            scorer.agent = agent
            print(
                f"{task}: a fresh critic on half of each task's episodes, pooled: "
                + stage_aucs(scorer.scores(data, test), data, test)
            )


if __name__ == "__main__":
    main()
