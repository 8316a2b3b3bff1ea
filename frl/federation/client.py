"""A vehicle: its environment, its DDPG agent and its local training loop, with no transport.

:class:`VehicleClient` is what every transport wraps: the worker processes of
:mod:`frl.federation.workers` and the Flower vehicle process of
:mod:`frl.flower.vehicle`. Whatever leaves a vehicle goes through
:meth:`VehicleClient.train` (a :class:`LocalUpdate`) or
:meth:`VehicleClient.get_parameters`: model parameters and scalar metrics, never
observations, replay data, optimizer moments or noise state (the paper's privacy claim,
Section I; tested in tests/test_federation_client.py).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable, Generator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from torch import Tensor

from frl.agents import DDPG, DDPGConfig, discounted_returns, is_target_key
from frl.agents.learn import acting_step, read_losses
from frl.envs import EnvConfig, IntersectionEnv, RewardConfig
from frl.episodes import EpisodeRecord, Policy, run_episodes, speed_summary
from frl.federation.vehicle_snapshot import (
    VehicleSnapshot,
    read_vehicle_snapshot,
    snapshot_path,
    write_vehicle_snapshot,
)
from frl.fileio import write_json_atomic
from frl.policies import install_guide

LOSS_NAMES: tuple[str, ...] = (
    "critic_loss", "actor_loss", "q_mean", "td_error", "imitation_loss",
    "cost_critic_loss", "cost_q_mean", "lagrange_multiplier", "collision_rate",
)  # fmt: skip
"""Per-step learning statistics a client reports (NaN on steps without an update);
``td_error`` is the batch's mean |Q(s, a) - (r + gamma Q'(s', mu'(s')))|; a guided agent's
``imitation_loss`` (weighted); under a collision budget the cost critic's loss and mean
Q_c, the multiplier lambda and the training collision rate it follows."""

ACTION_SERIES: tuple[str, ...] = ("executed", "policy")
"""Per-step actions a client reports: what it drove (noise and warm-up included), and
what its deterministic policy proposed before the noise (NaN during the random warm-up)."""

PROGRESS_EVERY_STEPS = 100

_SEED_HALF_RANGE = 2**30


def training_sumo_seed(base_seed: int, restart: int) -> int:
    """SUMO seed of a client's ``restart``-th simulation start. Always even.

    Evaluation seeds are always odd (:func:`frl.federation.plan.evaluation_seeds`), so
    test traffic never replays a training simulation.
    """
    mixed = np.random.SeedSequence([int(base_seed), int(restart)]).generate_state(1, np.uint32)
    return 2 * (int(mixed[0]) % _SEED_HALF_RANGE)


@dataclass(frozen=True)
class ClientSpec:
    """Everything needed to build one vehicle; picklable, so a worker process can build it."""

    index: int
    task: str
    """``left``, ``straight``, ``right``, or ``random`` (Central-DDPG)."""
    env: EnvConfig
    reward: RewardConfig
    agent: DDPGConfig
    agent_seed: int
    env_seed: int
    """Base of the SUMO seeds of this vehicle's training simulations."""
    device: str = "cpu"
    init_seed: int | None = None
    """Seed of the network initialisation when the clients share one initial model (the
    same for every client); None: drawn from ``agent_seed``."""
    proximal_mu: float = 0.0
    """FedProx: weight of mu/2 ||w - w_global||^2 in the critic and actor losses, w_global
    the global model last received (0: plain local training)."""

    @property
    def name(self) -> str:
        """``client{index}_{task}``, the prefix of this vehicle's TensorBoard tags."""
        return f"client{self.index}_{self.task}"


@dataclass
class LocalUpdate:
    """What a vehicle sends to the roadside unit after a round of local training."""

    client: str
    num_steps: int
    """Environment steps taken in this round (the FedAvg weight under ``weighting=steps``)."""
    total_steps: int
    """Environment steps this vehicle has taken since the run began."""
    step_rewards: np.ndarray
    """float32 (num_steps,): the instantaneous reward of every step (``train/step_reward``)."""
    episodes: list[EpisodeRecord]
    """Episodes that ended in this round."""
    losses: dict[str, np.ndarray] = field(default_factory=dict)
    """float32 (num_steps,) per name in :data:`LOSS_NAMES`, NaN where no update ran."""
    actions: dict[str, np.ndarray] = field(default_factory=dict)
    """float32 (num_steps,) per name in :data:`ACTION_SERIES` (the first action dimension)."""
    parameters: dict[str, Tensor] | None = None
    """The model upload (a subset of the agent's federated state), or None if not asked."""
    cpu_time_s: float = 0.0
    """CPU seconds the vehicle's process spent on this round (for the timing benchmarks)."""
    wall_time_s: float = 0.0
    """Wall seconds of this round's local training on the vehicle."""


ProgressCallback = Callable[..., None]
RoundSteps = Generator[Any, Any, LocalUpdate]
"""A vehicle's round, a step at a time (:meth:`VehicleClient.training_round`)."""
PolicyActions = Callable[[list[Any]], Sequence[np.ndarray | None]]
"""The vehicles' policy actions on their observations, computed together (one list entry
per vehicle; None: the vehicle computes its own)."""


def drive_rounds(
    rounds: Sequence[RoundSteps],
    update: Callable[[], Sequence[Mapping[str, Any]]],
    act: PolicyActions | None = None,
) -> list[LocalUpdate]:
    """Drive vehicles' rounds of equal length in lockstep: ``act`` gives every vehicle its
    policy action on its observation at once (None: each computes its own), each takes a
    step, then ``update()`` gives each its step's update losses (one list entry per round,
    in order); their :class:`LocalUpdate` s. The time of the shared acting and updates
    is shared among them equally."""
    results: list[LocalUpdate | None] = [None] * len(rounds)
    observations = [next(steps) for steps in rounds]
    cpu = wall = 0.0

    def shared(work: Callable[[], Any]) -> Any:
        """``work()``, its time counted as the vehicles' shared time."""
        nonlocal cpu, wall
        cpu_started, wall_started = time.process_time(), time.perf_counter()
        result = work()
        cpu += time.process_time() - cpu_started
        wall += time.perf_counter() - wall_started
        return result

    while True:
        actions = [None] * len(rounds) if act is None else shared(lambda: act(observations))
        for steps, action in zip(rounds, actions, strict=True):
            steps.send(action)
        losses = shared(update)
        for k, (steps, step_losses) in enumerate(zip(rounds, losses, strict=True)):
            try:
                observations[k] = steps.send(step_losses)
            except StopIteration as finished:
                results[k] = finished.value
        if all(result is not None for result in results):
            share = len(rounds)
            return [
                dataclasses.replace(
                    result,
                    cpu_time_s=result.cpu_time_s + cpu / share,
                    wall_time_s=result.wall_time_s + wall / share,
                )
                for result in results
                if result is not None
            ]
        if any(result is not None for result in results):
            raise ValueError("rounds driven in lockstep must take as many steps")


class VehicleClient:
    """One vehicle: an :class:`IntersectionEnv` for its task and a :class:`DDPG` agent.

    Episodes run on across rounds: a round boundary (and a parameter download) happens
    between two steps, as a vehicle keeps driving while it talks to the roadside unit.
    Owns one SUMO simulation, so with the default libsumo backend there is one client
    per process.
    """

    def __init__(self, spec: ClientSpec) -> None:
        self.spec = spec
        self.env = IntersectionEnv(dataclasses.replace(spec.env, task=spec.task), spec.reward)
        self.agent = DDPG(
            self.env.observation_space,
            self.env.action_space,
            spec.agent,
            seed=spec.agent_seed,
            init_seed=spec.init_seed,
            device=spec.device,
        )
        install_guide(self.agent, self.env.config)
        if spec.proximal_mu:
            self.agent.set_proximal_anchor(spec.proximal_mu)
        self._observation: np.ndarray | None = None
        self._restarts = 0
        """SUMO (re)starts so far; the next start uses ``training_sumo_seed(env_seed, n)``."""
        self._needs_restart = True
        self._episodes_total = 0
        self._last_return: float | None = None
        # The running episode: its return, speeds and critic bias are computed at its end.
        self._episode_observations: list[np.ndarray] = []
        self._episode_actions: list[np.ndarray] = []
        self._episode_rewards: list[float] = []
        self._episode_speeds: list[float] = []

    @property
    def name(self) -> str:
        return self.spec.name

    # ---------------------------------------------------------------- training
    def train(
        self,
        num_steps: int,
        upload: bool = True,
        include_targets: bool = True,
        progress: ProgressCallback | None = None,
    ) -> LocalUpdate:
        """Take ``num_steps`` environment steps, learning after each (Section III.C.1).

        Args:
            num_steps: environment steps of this round.
            upload: attach the model parameters to the update.
            include_targets: upload target networks too (``federation.targets=average``).
            progress: called as ``progress(steps=, total_steps=, episodes=, last_return=)``
                every :data:`PROGRESS_EVERY_STEPS` steps and at each episode end.
        """
        steps = self.training_round(num_steps, upload, include_targets, progress)
        return drive_rounds([steps], lambda: [self.agent.update_unread()])[0]

    def training_round(
        self,
        num_steps: int,
        upload: bool = True,
        include_targets: bool = True,
        progress: ProgressCallback | None = None,
    ) -> RoundSteps:
        """:meth:`train` one step at a time, its acting and updates shared with whoever
        drives it: a generator that yields each step's observation and takes the policy's
        action on it back (``send``; None: the agent computes it), then yields after the
        step's transition is observed and takes that step's update losses back (``{}``
        where no update ran), and returns the round's :class:`LocalUpdate`.
        :func:`drive_rounds` drives several in lockstep, so that the vehicles of a process
        can act in one batched forward pass and learn in one stacked update."""
        if num_steps <= 0:
            raise ValueError(f"num_steps must be positive, got {num_steps}")
        agent, env = self.agent, self.env
        cpu_started, wall_started = time.process_time(), time.perf_counter()
        cpu_paused = wall_paused = 0.0
        rewards = np.empty(num_steps, np.float32)
        losses = {name: np.full(num_steps, np.nan, np.float32) for name in LOSS_NAMES}
        actions = {name: np.empty(num_steps, np.float32) for name in ACTION_SERIES}
        episodes: list[EpisodeRecord] = []
        updates: list[tuple[int, Mapping[str, Any]]] = []  # read once, at the round's end
        for i in range(num_steps):
            if self._observation is None:
                self._start_episode()
            observation = self._observation
            # The others' steps are not this vehicle's time; the shared acting and updates
            # are (the driver adds their share).
            cpu_yielded, wall_yielded = time.process_time(), time.perf_counter()
            policy_action = yield observation
            cpu_paused += time.process_time() - cpu_yielded
            wall_paused += time.perf_counter() - wall_yielded
            step = acting_step(agent, env, observation, policy_action)
            cpu_yielded, wall_yielded = time.process_time(), time.perf_counter()
            step_losses = yield None
            cpu_paused += time.process_time() - cpu_yielded
            wall_paused += time.perf_counter() - wall_yielded
            action, reward, info = step.action, step.reward, step.info
            next_observation, terminated, truncated = step.next_obs, step.terminated, step.truncated
            actions["executed"][i] = action[0]
            actions["policy"][i] = agent.last_policy_action[0]
            if step_losses:
                updates.append((i, step_losses))
            rewards[i] = reward
            self._episode_observations.append(observation)
            self._episode_actions.append(action)
            self._episode_rewards.append(float(reward))
            self._episode_speeds.append(float(info["ego_speed"]))
            ended = terminated or truncated
            if ended:
                # Summed in step order from 0, as a running total would be.
                episode_return = sum(self._episode_rewards)
                mean_speed, stopped = speed_summary(
                    self._episode_speeds, env.reward_config.moving_speed
                )
                episodes.append(
                    EpisodeRecord(
                        task=info["task"],
                        episode_return=episode_return,
                        collision=bool(info["collision"]),
                        arrived=bool(info["arrived"]),
                        timeout=bool(truncated and not terminated),
                        steps=int(info["travel_time_steps"]),
                        end_step=agent.num_env_steps,
                        mean_speed=mean_speed,
                        stopped_steps=stopped,
                        critic_bias=self._critic_bias() if terminated else None,
                        teacher_drove=agent.explorer.teacher_driving,
                    )
                )
                self._episodes_total += 1
                self._last_return = episode_return
                self._observation = None
            else:
                self._observation = next_observation
            if progress is not None and (ended or (i + 1) % PROGRESS_EVERY_STEPS == 0):
                progress(
                    steps=i + 1,
                    total_steps=agent.num_env_steps,
                    episodes=self._episodes_total,
                    last_return=self._last_return,
                )
        for (i, _), read in zip(updates, read_losses([u for _, u in updates]), strict=True):
            for name, value in read.items():
                if name in losses:
                    losses[name][i] = value
        return LocalUpdate(
            client=self.name,
            num_steps=num_steps,
            total_steps=agent.num_env_steps,
            step_rewards=rewards,
            episodes=episodes,
            losses=losses,
            actions=actions,
            parameters=self.get_parameters(include_targets) if upload else None,
            cpu_time_s=time.process_time() - cpu_started - cpu_paused,
            wall_time_s=time.perf_counter() - wall_started - wall_paused,
        )

    def _start_episode(self) -> None:
        if self._needs_restart:
            seed = training_sumo_seed(self.spec.env_seed, self._restarts)
            self._observation, _ = self.env.reset(seed=seed)
            self._restarts += 1
            self._needs_restart = False
        else:  # a new ego in the traffic that kept flowing
            self._observation, _ = self.env.reset()
        self._episode_observations = []
        self._episode_actions = []
        self._episode_rewards = []
        self._episode_speeds = []
        self.agent.episode_start()

    def _critic_bias(self) -> float:
        """Mean Q(s_t, a_t) - G_t over the episode that just terminated (critic bias)."""
        q = self.agent.critic_values(self._episode_observations, np.stack(self._episode_actions))
        returns = discounted_returns(self._episode_rewards, self.agent.config.gamma)
        return float(np.mean(q - returns))

    # -------------------------------------------------------------- parameters
    def get_parameters(self, include_targets: bool = True) -> dict[str, Tensor]:
        """CPU copies of the model parameters: the agent's federated state, without the
        target networks unless ``include_targets``. Nothing else ever leaves the vehicle."""
        state = self.agent.federated_state()
        if include_targets:
            return state
        return {k: v for k, v in state.items() if not is_target_key(k)}

    def set_parameters(self, parameters: dict[str, Tensor], sync_targets: bool = False) -> None:
        """Load the global model. Keys must cover the online networks; target keys are
        optional. ``sync_targets`` then copies online -> target (``targets=resync``)."""
        state = self.agent.federated_state()
        unexpected = sorted(set(parameters) - set(state))
        if unexpected:
            raise ValueError(f"{self.name}: unexpected parameter {unexpected[0]!r}")
        missing = sorted(k for k in state if not is_target_key(k) and k not in parameters)
        if missing:
            raise ValueError(f"{self.name}: global model lacks {missing[0]!r}")
        state.update(parameters)
        self.agent.load_federated_state(state)
        if sync_targets:
            self.agent.sync_targets()
        if self.spec.proximal_mu:
            self.agent.set_proximal_anchor(self.spec.proximal_mu)

    # -------------------------------------------------------------- evaluation
    def policy(self) -> Policy:
        """The deterministic policy (exploration off)."""
        return lambda observation: self.agent.act(observation, explore=False)

    def evaluate(self, task: str, seeds: list[int]) -> list[EpisodeRecord]:
        """Test episodes with exploration off, one per seed (restarts SUMO each time).

        The episode in progress, if any, is dropped; training resumes on a fresh start.
        """
        records = run_episodes(self.env, self.policy(), task, seeds, self.agent.episode_start)
        self._observation = None
        self._needs_restart = True
        return records

    # ------------------------------------------------------------- checkpoints
    def save(self, directory: str | os.PathLike[str]) -> None:
        """Write this vehicle's full state for resume: agent with replay buffer, optimizer
        moments, noise and generators, the client's counters and its drive (the
        environment and the episode in progress). Stays on the vehicle."""
        directory = Path(directory)
        self.agent.save(directory / f"{self.name}.pt", include_buffer=True)
        write_vehicle_snapshot(snapshot_path(directory, self.name), self._snapshot())
        write_json_atomic(
            directory / f"{self.name}.json",
            {
                "restarts": self._restarts,
                "episodes_total": self._episodes_total,
                "last_return": self._last_return,
                "num_env_steps": self.agent.num_env_steps,
            },
        )

    def load(self, directory: str | os.PathLike[str]) -> bool:
        """Restore :meth:`save`; the vehicle goes on driving exactly where it stood.

        Returns False for a checkpoint written before vehicles saved their drive: the
        episode that was running then is dropped and the next step starts a new simulation.
        """
        directory = Path(directory)
        self.agent.restore(directory / f"{self.name}.pt")
        if self.spec.proximal_mu:
            # Checkpoints follow the download of the round's global model: the anchor.
            self.agent.set_proximal_anchor(self.spec.proximal_mu)
        state = json.loads((directory / f"{self.name}.json").read_text())
        self._restarts = int(state["restarts"])
        self._episodes_total = int(state["episodes_total"])
        self._last_return = state["last_return"]
        path = snapshot_path(directory, self.name)
        if not path.exists():
            self._observation = None
            self._needs_restart = True
            return False
        self._resume_snapshot(read_vehicle_snapshot(path))
        return True

    def _snapshot(self) -> VehicleSnapshot:
        """Where this vehicle stands: its simulation and the episode in progress."""
        space = self.env.observation_space
        snapshot = None if self._needs_restart else self.env.snapshot()
        if self._observation is None:  # between episodes: the lists hold the one that ended
            no_steps = np.empty((0, spaces.flatdim(space)), np.float32)
            no_actions = np.empty((0, *self.env.action_space.shape), np.float32)
            return VehicleSnapshot(snapshot, None, no_steps, no_actions, [], [])
        # Mid-episode at a round's end: every episode has taken a step by then.
        return VehicleSnapshot(
            snapshot=snapshot,
            observation=spaces.flatten(space, self._observation),
            episode_observations=np.stack(
                [spaces.flatten(space, o) for o in self._episode_observations]
            ),
            episode_actions=np.stack(self._episode_actions),
            episode_rewards=list(self._episode_rewards),
            episode_speeds=list(self._episode_speeds),
        )

    def _resume_snapshot(self, drive: VehicleSnapshot) -> None:
        """Put the simulation and the running episode back as :meth:`_drive` saw them."""
        self._needs_restart = drive.snapshot is None
        if drive.snapshot is not None:
            self.env.restore(drive.snapshot)
        space = self.env.observation_space
        self._observation = (
            None if drive.observation is None else spaces.unflatten(space, drive.observation)
        )
        self._episode_observations = [
            spaces.unflatten(space, row) for row in drive.episode_observations
        ]
        self._episode_actions = list(drive.episode_actions)
        self._episode_rewards = drive.episode_rewards
        self._episode_speeds = drive.episode_speeds

    def save_model(self, path: str | os.PathLike[str]) -> None:
        """Write the model alone (no replay buffer), loadable with ``DDPG.from_checkpoint``."""
        self.agent.save(path, include_buffer=False)

    def model_file(self) -> bytes:
        """The bytes :meth:`save_model` writes, for a roadside unit on another host."""
        return self.agent.save_bytes()

    def close(self) -> None:
        self.env.close()
