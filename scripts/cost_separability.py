"""Whether a run's collisions can be told apart at the approach, by its cost critic and
by a fresh network of the same shape fitted on far more of the car's own driving.

    python scripts/cost_separability.py RUN_DIR [--episodes N] [--tasks left,straight]

Drives the run's model without noise (as it is tested) on ``N`` episodes per task from
seeds no test uses, keeps every state of the approach (from 30 m before the stop line to
15 m past it) with the action taken and whether the episode ended in a collision, and
asks, on the states of held-out episodes more than ``--lead`` seconds before their end:

- **the run's own cost critic**: how well Q_c(s, a) ranks the states of episodes that
  collided above those that did not (ROC AUC; 0.5 is blind, 1 separates them);
- **a fresh critic**: the run's critic architecture (vehicles encoder, the same trunk),
  newly initialised and fitted by logistic loss to the same label on the other
  episodes, once on all of them and once on a tenth (about what one vehicle drives in
  a round). Where the fresh critic on all the episodes ranks far better than the run's
  own, the outcome is in the states and the cost critic did not learn it; where both
  rank alike, more of the same driving would not teach it either.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from frl import run_directory as rundir
from frl.agents import DDPG, SparseRows
from frl.agents.networks import Critic, build_network
from frl.envs import IntersectionEnv
from frl.evaluate import run_settings
from frl.federation.assembly import evaluation_env

APPROACH_M = (-15.0, 30.0)
"""The stop-line distances (m; negative: past the line) whose states are kept."""
SEED_BASE = 70_000
"""Episode seeds start here: above every run's test seeds (docs/training.md)."""


def drive(agent: DDPG, env: IntersectionEnv, seeds: range) -> dict[str, np.ndarray]:
    """The approach states of the noise-free model on ``seeds``: observations, actions,
    the episode each belongs to, steps left to its end and whether it collided."""
    observations, actions, episodes, steps_left, collided, distances = [], [], [], [], [], []
    for episode, seed in enumerate(seeds):
        observation, _ = env.reset(seed=seed)
        kept: list[int] = []
        step = 0
        while True:
            action = agent.act(observation, explore=False)
            if APPROACH_M[0] < env.stop_line_distance_m <= APPROACH_M[1]:
                observations.append(
                    np.asarray(agent.layout.flat(observation), np.float16).reshape(-1)
                )
                actions.append(np.asarray(action, dtype=np.float32).reshape(-1))
                distances.append(env.stop_line_distance_m)
                kept.append(step)
            observation, _, terminated, truncated, info = env.step(action)
            step += 1
            if terminated or truncated:
                break
        episodes += [episode] * len(kept)
        steps_left += [step - k for k in kept]
        collided += [bool(info["collision"])] * len(kept)
    return {
        "obs": np.stack(observations),
        "actions": np.stack(actions),
        "episode": np.array(episodes),
        "steps_left": np.array(steps_left),
        "collided": np.array(collided),
        "distance": np.array(distances),
    }


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """The probability that a positive's score exceeds a negative's (ties count half)."""
    order = np.argsort(scores, kind="stable")
    ranks = np.empty(len(scores))
    sorted_scores = scores[order]
    # average ranks over ties
    _, first, counts = np.unique(sorted_scores, return_index=True, return_counts=True)
    average = first + (counts - 1) / 2.0 + 1
    ranks[order] = np.repeat(average, counts)
    positives = labels.sum()
    negatives = len(labels) - positives
    if positives == 0 or negatives == 0:
        return float("nan")
    return float((ranks[labels].sum() - positives * (positives + 1) / 2) / (positives * negatives))


def as_input(agent: DDPG, obs: np.ndarray) -> torch.Tensor | SparseRows:
    x = torch.from_numpy(obs.astype(np.float32))
    return SparseRows.from_dense(x) if agent.sparse else x


def fit_fresh_critic(
    agent: DDPG, data: dict[str, np.ndarray], rows: np.ndarray, updates: int, seed: int
) -> Critic:
    """The run's critic architecture, new weights, fitted to ``collided`` on ``rows``."""
    generator = torch.Generator().manual_seed(seed)
    critic = build_network(
        Critic, agent.obs_dim, agent.action_dim, agent.config, agent.layout, generator,
        torch.device("cpu"),
    )  # fmt: skip
    optimizer = torch.optim.Adam(critic.parameters(), lr=3e-4)
    labels = torch.from_numpy(data["collided"].astype(np.float32))
    actions = torch.from_numpy(agent.scale.to_unit(data["actions"], batch=True).astype(np.float32))
    rng = np.random.default_rng(seed)
    positives, negatives = rows[data["collided"][rows]], rows[~data["collided"][rows]]
    for _ in range(updates):
        # half of each batch from collided episodes: they are a tenth of the states
        batch = np.concatenate([rng.choice(positives, 128), rng.choice(negatives, 128)])
        logits = critic(as_input(agent, data["obs"][batch]), actions[batch])
        loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, labels[batch])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return critic


def scores_of(
    critic: Critic, agent: DDPG, data: dict[str, np.ndarray], rows: np.ndarray
) -> np.ndarray:
    actions = torch.from_numpy(
        agent.scale.to_unit(data["actions"][rows], batch=True).astype(np.float32)
    )
    out = []
    with torch.no_grad():
        for start in range(0, len(rows), 4096):
            part = rows[start : start + 4096]
            out.append(critic(as_input(agent, data["obs"][part]), actions[start : start + 4096]))
    return torch.cat(out).numpy()


def stage_aucs(scores: np.ndarray, data: dict[str, np.ndarray], test: np.ndarray) -> str:
    """AUC on all held-out states, on those before the stop line and on those past it."""
    labels = data["collided"][test]
    before = data["distance"][test] > 0
    parts = [("all", np.ones_like(before)), ("before the line", before), ("past it", ~before)]
    return ", ".join(f"{name} {roc_auc(scores[rows], labels[rows]):.3f}" for name, rows in parts)


def task_data(args: argparse.Namespace, settings, files, task: str) -> tuple[DDPG, dict]:  # type: ignore[no-untyped-def]
    """The model of ``task`` and its driven approach states, from ``--cache`` if there."""
    env = IntersectionEnv(replace(evaluation_env(settings, task), task=task))
    try:
        agent = DDPG.from_checkpoint(files[task][0], env.observation_space, env.action_space)
        cache = args.cache / f"{task}-{args.episodes}.npz" if args.cache else None
        if cache is not None and cache.exists():
            with np.load(cache) as stored:
                return agent, dict(stored)
        data = drive(agent, env, range(SEED_BASE, SEED_BASE + args.episodes))
    finally:
        env.close()
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        np.savez(cache, **data)
    return agent, data


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--tasks", default="left,straight")
    parser.add_argument("--lead", type=float, default=1.0, help="seconds before the end")
    parser.add_argument("--updates", type=int, default=4000)
    parser.add_argument("--cache", type=Path, default=None, help="keep the driven states here")
    args = parser.parse_args()
    torch.manual_seed(0)
    settings = run_settings(args.run_dir)
    files = rundir.model_files(args.run_dir)
    for task in args.tasks.split(","):
        agent, data = task_data(args, settings, files, task)
        step_s = settings.env.scenario.step_length
        held_out = data["episode"] % 5 == 0
        lead = data["steps_left"] * step_s > args.lead
        test = np.flatnonzero(held_out & lead)
        train = np.flatnonzero(~held_out)
        labels = data["collided"][test]
        collisions = len(np.unique(data["episode"][data["collided"]]))
        own = agent.critic_values(
            data["obs"][test].astype(np.float32), data["actions"][test], cost=True
        )
        print(
            f"{task}: {args.episodes} episodes, {collisions} collided; {len(data['obs'])} "
            f"approach states, {len(test)} held out ({int(labels.sum())} from collided "
            f"episodes), more than {args.lead:.1f} s before the end. AUC:"
        )
        print(f"  the run's cost critic: {stage_aucs(own, data, test)}")
        train_episodes = np.unique(data["episode"][train])
        for share in (10, 2, 1):
            kept = train_episodes[: len(train_episodes) // share]
            rows = np.flatnonzero(np.isin(data["episode"], kept) & ~held_out)
            if not data["collided"][rows].any() or data["collided"][rows].all():
                print(f"  a fresh critic on {len(kept)} episodes: not both kinds to fit on")
                continue
            critic = fit_fresh_critic(agent, data, rows, args.updates, seed=1)
            scores = scores_of(critic, agent, data, test)
            print(f"  a fresh critic on {len(kept)} episodes: {stage_aucs(scores, data, test)}")


if __name__ == "__main__":
    main()
