"""The training step, and ``DDPG.learn``: one agent on one gymnasium environment, the loop
of Stable-Baselines3's ``model.learn``, with its TensorBoard tags where asked.

A training step (:func:`training_step`) is act, step, observe (gymnasium's
``terminated``: a time-limit cut-off still bootstraps) and update; at an episode's end the
loop resets and calls :meth:`DDPG.episode_start`. :func:`learn` and the federated
vehicles (frl.federation.client) run the same step.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple, Protocol, TypeVar

import numpy as np
import torch

EPISODE_WINDOW = 100
"""Episodes in ``rollout/ep_rew_mean`` and ``ep_len_mean`` (Stable-Baselines3's window)."""
LOSS_WINDOW = 100
"""Environment steps over which ``train/*`` losses are averaged before each point."""


class Learner(Protocol):
    """What :func:`learn` needs of an agent (:class:`frl.agents.DDPG` has it)."""

    seed: int
    obs_shape: tuple[int, ...]
    action_shape: tuple[int, ...]
    num_env_steps: int
    learn_calls: int
    episode_returns: list[float]
    episode_lengths: list[int]

    def act(self, obs: Any, explore: bool = True) -> np.ndarray: ...
    def observe(
        self, obs: Any, action: Any, reward: float, next_obs: Any, terminated: bool,
        cost: float = 0.0,
    ) -> None: ...  # fmt: skip
    def update(self) -> dict[str, float]: ...
    def update_unread(self) -> Mapping[str, Any]: ...
    def episode_start(self) -> None: ...


class Step(NamedTuple):
    """What one training step did and saw."""

    action: np.ndarray
    next_obs: Any
    reward: float
    terminated: bool
    truncated: bool
    info: dict[str, Any]
    losses: Mapping[str, Any]
    """The update's losses, unread (tensors or floats: :func:`read_losses`); empty where
    no update was due."""


def training_step(agent: Learner, env: Any, obs: Any) -> Step:
    """Act with exploration, step ``env``, observe the transition (with the step's cost,
    ``info["cost"]``, where the environment reports one), update if due."""
    return acting_step(agent, env, obs)._replace(losses=agent.update_unread())


def acting_step(
    agent: Learner, env: Any, obs: Any, policy_action: np.ndarray | None = None
) -> Step:
    """:func:`training_step` without its update (``losses`` empty): for agents whose
    update is taken elsewhere, with others' (:mod:`frl.agents.stacked`). ``policy_action``:
    the policy's action on ``obs``, computed with others' (None: the agent computes it)."""
    action = (
        agent.act(obs) if policy_action is None else agent.act(obs, policy_action=policy_action)
    )
    next_obs, reward, terminated, truncated, info = env.step(action)
    cost = float(info.get("cost", 0.0)) if isinstance(info, dict) else 0.0
    agent.observe(obs, action, float(reward), next_obs, terminated, cost=cost)
    return Step(action, next_obs, float(reward), terminated, truncated, info, {})


def read_losses(steps: Sequence[Mapping[str, Any]]) -> list[dict[str, float]]:
    """The losses of several updates as floats, their tensors read in one go: a read
    waits for the device, once here rather than once a loss and an update."""
    tensors = [v for losses in steps for v in losses.values() if isinstance(v, torch.Tensor)]
    # float() is exact for every loss dtype (float32, bf16): the values are .item()'s.
    values = iter(torch.stack([t.float() for t in tensors]).tolist() if tensors else [])
    return [
        {
            name: next(values) if isinstance(v, torch.Tensor) else float(v)
            for name, v in step.items()
        }
        for step in steps
    ]


AgentT = TypeVar("AgentT", bound=Learner)
LearnCallback = Callable[[Any, int, dict], "bool | None"]
"""``callback(agent, step, info)`` after every step of :func:`learn`; ``False`` stops it."""


def learn(
    agent: AgentT,
    env: Any,
    total_timesteps: int,
    callback: LearnCallback | None = None,
    progress_bar: bool = False,
    tensorboard_log: str | os.PathLike[str] | None = None,
    seed: int | None = None,
) -> AgentT:
    """Train ``agent`` on ``env`` for ``total_timesteps`` environment steps; return it.

    Args:
        env: a gymnasium environment whose spaces have the agent's shapes (a single
            environment: a vector of them would need one agent step per environment).
        total_timesteps: steps in this call; a later call goes on from the agent's state
            (buffer, counters, noise) with a fresh episode.
        callback: ``callback(agent, step, info)`` after each step (``step`` counts from 1
            in this call); returning ``False`` stops training there.
        progress_bar: a tqdm bar over the steps.
        tensorboard_log: a directory for TensorBoard events: ``rollout/ep_rew_mean`` and
            ``rollout/ep_len_mean`` over the last 100 episodes at each episode's end,
            ``rollout/episode_return``, and the update losses (``train/critic_loss``,
            ``train/actor_loss``, ...) averaged over windows of 100 steps; the x axis is
            the agent's total environment steps.
        seed: the first reset's seed; None: the agent's seed on its first ``learn``,
            unseeded resets after (the environment's own random stream goes on).

    The returns of finished episodes are appended to ``agent.episode_returns``.

    Raises:
        ValueError: a non-positive budget, or spaces that do not match the agent's.
        RuntimeError: a guided agent (``DDPGConfig.guide``) without its teacher
            (:meth:`frl.agents.DDPG.set_guide`).
    """
    if isinstance(total_timesteps, bool) or not isinstance(total_timesteps, (int, np.integer)):
        raise ValueError(f"total_timesteps must be a positive integer, got {total_timesteps!r}")
    if total_timesteps <= 0:
        raise ValueError(f"total_timesteps must be a positive integer, got {total_timesteps}")
    _check_spaces(agent, env)
    if agent.needs_guide:
        raise RuntimeError(
            f"this agent learns from a teacher (guide={agent.config.guide!r}): install it "
            "first, agent.set_guide(policy), or frl.policies.install_guide(agent, env.config)"
        )
    if seed is None and agent.learn_calls == 0:
        seed = agent.seed
    writer = _summary_writer(tensorboard_log)
    from tqdm.auto import tqdm

    bar = tqdm(total=int(total_timesteps), unit="step", disable=not progress_bar)
    window: list[Mapping[str, Any]] = []
    try:
        obs, _ = env.reset(seed=seed)
        agent.learn_calls += 1
        agent.episode_start()
        episode_return, episode_steps = 0.0, 0
        for step in range(1, int(total_timesteps) + 1):
            step_done = training_step(agent, env, obs)
            if step_done.losses and writer is not None:
                window.append(step_done.losses)
            obs = step_done.next_obs
            episode_return += step_done.reward
            episode_steps += 1
            if writer is not None and agent.num_env_steps % LOSS_WINDOW == 0:
                losses: dict[str, list[float]] = {}
                for read in read_losses(window):
                    for name, value in read.items():
                        losses.setdefault(name, []).append(value)
                for name, values in losses.items():
                    writer.add_scalar(f"train/{name}", float(np.mean(values)), agent.num_env_steps)
                window.clear()
            if step_done.terminated or step_done.truncated:
                agent.episode_returns.append(episode_return)
                agent.episode_lengths.append(episode_steps)
                if writer is not None:
                    at = agent.num_env_steps
                    returns = agent.episode_returns[-EPISODE_WINDOW:]
                    lengths = agent.episode_lengths[-EPISODE_WINDOW:]
                    writer.add_scalar("rollout/ep_rew_mean", float(np.mean(returns)), at)
                    writer.add_scalar("rollout/ep_len_mean", float(np.mean(lengths)), at)
                    writer.add_scalar("rollout/episode_return", episode_return, at)
                obs, _ = env.reset()
                agent.episode_start()
                episode_return, episode_steps = 0.0, 0
            bar.update(1)
            if callback is not None and callback(agent, step, step_done.info) is False:
                break
    finally:
        bar.close()
        if writer is not None:
            writer.close()
    return agent


def _check_spaces(agent: Learner, env: Any) -> None:
    observation_shape = tuple(getattr(env.observation_space, "shape", ()) or ())
    action_shape = tuple(getattr(env.action_space, "shape", ()) or ())
    if observation_shape != agent.obs_shape or action_shape != agent.action_shape:
        raise ValueError(
            f"the environment's spaces (observation {observation_shape}, action "
            f"{action_shape}) do not match the agent's (observation {agent.obs_shape}, "
            f"action {agent.action_shape})"
        )


def _summary_writer(log_dir: str | os.PathLike[str] | None) -> Any:
    if log_dir is None:
        return None
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter(os.fspath(log_dir))
