"""DDPG (Lillicrap et al. 2016) for gymnasium Box spaces, with a federated-state interface."""

from __future__ import annotations

import copy
import os
import types
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from gymnasium import spaces
from torch import Tensor, nn

from frl.agents.acting import actor_action
from frl.agents.checkpoint import CheckpointError, read_checkpoint, write_checkpoint
from frl.agents.config import DDPGConfig
from frl.agents.functional import hard_update, soft_update, td_target
from frl.agents.guide import (
    guide_weight_at,
    imitation_loss,
    lower_only,
    q_filter,
    residual_action,
)
from frl.agents.learn import LearnCallback, learn
from frl.agents.n_step import NStepAccumulator
from frl.agents.networks import Actor, Critic, init_mlp_
from frl.agents.noise import generator_state, make_noise, set_generator_state
from frl.agents.observations import ObservationLayout, space_from_record
from frl.agents.precision import autocast, resolve_precision
from frl.agents.prioritized import lap_critic_loss, lap_priority
from frl.agents.replay_buffer import Batch, ReplayBuffer
from frl.agents.sparse_linear import SparseRows
from frl.agents.vehicle_encoder import VehicleSetEncoder

NETWORK_NAMES: tuple[str, ...] = (
    "actor", "critic", "actor_target", "critic_target", "critic2", "critic2_target",
)  # fmt: skip
"""Prefixes of :meth:`DDPG.federated_state` keys, e.g. ``critic_target.layers.0.weight``;
``critic2*`` only with ``twin_critics``."""
_TARGET_PREFIXES = ("actor_target.", "critic_target.", "critic2_target.")


@dataclass
class _HeldDecision:
    """The action being held (``action_repeat`` > 1) and what it has earned so far."""

    obs: np.ndarray
    action: np.ndarray
    reward: float = 0.0
    """Discounted sum of the rewards of the steps taken so far."""
    steps: int = 0
    next_obs: np.ndarray | None = None


def is_target_key(name: str) -> bool:
    """Whether a federated-state key belongs to a target network."""
    return name.startswith(_TARGET_PREFIXES)


def _make_adam(params: list[nn.Parameter], lr: float, device: torch.device) -> torch.optim.Adam:
    # The fused kernel updates all parameters in one pass; on CPU it exists since torch 2.4.
    try:
        return torch.optim.Adam(params, lr=lr, fused=True)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.Adam(params, lr=lr, foreach=device.type != "cpu" or None)


class _class_only:
    """A classmethod that refuses to be called on an instance: ``agent.load(path)`` would
    return a new agent and leave ``agent`` as it was, silently."""

    def __init__(self, method: Callable[..., Any]) -> None:
        self.method = method
        self.__doc__ = method.__doc__

    def __get__(self, instance: object, owner: type) -> Callable[..., Any]:
        if instance is not None:
            name = self.method.__name__
            raise TypeError(
                f"{owner.__name__}.{name} is a class method that returns a new agent: "
                f"agent = {owner.__name__}.{name}(path); to load a file into this agent, "
                "agent.restore(path)"
            )
        return types.MethodType(self.method, owner)


class DDPG:
    """Deep Deterministic Policy Gradient agent for a Box observation and a Box action space.

    Args:
        observation_space: any Box, or a Dict of Boxes (:mod:`frl.agents.observations`);
            observations are flattened. Large ones (see
            ``DDPGConfig.sparse_input``) take the sparse first-layer path and compact replay.
        action_space: a Box with finite bounds. The actor works in [-1, 1] and ``act``
            rescales to the bounds; noise is added in those normalised units.
        config: hyperparameters; ``None`` means the paper's Table II defaults.
        seed: seeds every random stream: network init, noise, replay sampling and warm-up
            actions each get a child of ``np.random.SeedSequence(seed)``.
        init_seed: seeds the network initialisation alone instead, so that agents with
            different ``seed`` start from the same networks (FedAvg's clients start from
            one initial global model). None: the init stream of ``seed``.
        device: where networks and training batches live; nothing requires a GPU.

    :meth:`learn` trains on a gymnasium environment, :meth:`predict` acts on one
    observation or a batch, :meth:`save` and ``DDPG.load`` write and read a file, as in
    Stable-Baselines3. Loops of their own (the federated clients') call
    :meth:`episode_start` at each reset, :meth:`act` to choose an action, :meth:`observe`
    with the transition and :meth:`update` once per environment step.
    """

    def __init__(
        self,
        observation_space: spaces.Box | spaces.Dict,
        action_space: spaces.Box,
        config: DDPGConfig | None = None,
        seed: int = 0,
        device: str | torch.device = "cpu",
        init_seed: int | None = None,
    ) -> None:
        self.layout = ObservationLayout(observation_space)
        """How observations become the flat vectors the networks and the buffer hold."""
        if not isinstance(action_space, spaces.Box):
            raise TypeError(f"action_space must be a gymnasium Box, got {action_space}")
        if not (np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))):
            raise ValueError("action_space bounds must be finite")
        self.config = config if config is not None else DDPGConfig()
        cfg = self.config
        self.seed = int(seed)
        self.device = torch.device(device)
        self.obs_shape: tuple[int, ...] = self.layout.shape
        """The stored observation's shape: a Box's own, a Dict's flat length."""
        self.obs_dim = self.layout.num_features
        self.action_shape: tuple[int, ...] = tuple(action_space.shape)
        self.action_dim = int(np.prod(self.action_shape, dtype=np.int64))
        self.action_low = action_space.low.astype(np.float64).reshape(-1)
        self.action_high = action_space.high.astype(np.float64).reshape(-1)
        self.sparse = cfg.use_sparse(self.obs_dim)
        """Networks see :class:`SparseRows` batches (same function, fewer multiply-adds)."""
        self.precision = resolve_precision(cfg.precision, self.device)
        """What the forward and backward passes compute in here: ``float32`` or ``bf16``
        (``DDPGConfig.precision`` resolved for this device)."""

        # spawn(5)'s first four children are spawn(4)'s: seeds written before the fifth
        # stream existed draw the same numbers.
        streams = np.random.SeedSequence(self.seed).spawn(5)
        init_seq, noise_seq, buffer_seq, explore_seq, target_noise_seq = streams
        if init_seed is not None:
            init_seq = np.random.SeedSequence(int(init_seed))
        init_gen = torch.Generator().manual_seed(int(init_seq.generate_state(1, np.uint64)[0]))
        # Built on the meta device so that nn.Linear's own init never draws from the
        # global torch RNG; then materialised and initialised from init_gen only.
        self.actor = self._build(Actor, init_gen)
        self.critic = self._build(Critic, init_gen)
        self.critic2: Critic | None = self._build(Critic, init_gen) if cfg.twin_critics else None
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.critic2_target = (
            None if self.critic2 is None else copy.deepcopy(self.critic2).requires_grad_(False)
        )
        online = [self.actor, self.critic, self.critic2]
        targets = [self.actor_target, self.critic_target, self.critic2_target]
        self._online_params = [p for net in online if net is not None for p in net.parameters()]
        self._target_params = [p for net in targets if net is not None for p in net.parameters()]
        self._critics = [net for net in (self.critic, self.critic2) if net is not None]
        self._proximal_mu = 0.0
        # FedProx: (parameter, the global model's value it is pulled towards).
        self._proximal_actor: list[tuple[Tensor, Tensor]] = []
        self._proximal_critic: list[tuple[Tensor, Tensor]] = []

        self.actor_optimizer = _make_adam(list(self.actor.parameters()), cfg.actor_lr, self.device)
        # One optimizer over both critics, as TD3's reference code and SB3 keep them.
        self.critic_optimizer = _make_adam(
            [p for critic in self._critics for p in critic.parameters()], cfg.critic_lr, self.device
        )
        self._target_noise_gen = torch.Generator(device=self.device).manual_seed(
            int(target_noise_seq.generate_state(1, np.uint64)[0])
        )
        self.noise = make_noise(
            cfg.noise,
            (self.action_dim,),
            np.random.default_rng(noise_seq),
            sigma=cfg.noise_sigma,
            theta=cfg.noise_theta,
            dt=cfg.noise_dt,
        )
        # Compact storage whenever the observation is large, even for a dense network.
        compact = cfg.sparse_input is True or self.obs_dim >= cfg.sparse_min_features
        self.buffer = ReplayBuffer(
            cfg.buffer_size,
            self.obs_shape,
            self.action_dim,
            np.random.default_rng(buffer_seq),
            sparse=compact,
            sparse_width=cfg.sparse_capacity,
            guided=cfg.guided,
            prioritized=cfg.replay == "lap",
        )
        self._explore_rng = np.random.default_rng(explore_seq)
        self._warmup_action: np.ndarray | None = None
        self._warmup_policy: Callable[[np.ndarray], Any] | None = None
        self._guide: Callable[[Any], Any] | None = None
        self._held_action: np.ndarray | None = None
        self._hold_left = 0
        self._stretch_action: np.ndarray | None = None
        self._stretch_left = 0
        self._decision: _HeldDecision | None = None
        self._n_step = NStepAccumulator(cfg.n_step, cfg.gamma)
        self.last_policy_action = np.full(self.action_dim, np.nan)
        """The deterministic policy's action (normalised to [-1, 1], before noise) behind
        the last :meth:`act`; NaN while warm-up actions are drawn uniformly."""
        self.num_env_steps = 0
        """Transitions passed to :meth:`observe`."""
        self.num_updates = 0
        """Gradient steps taken."""
        self.episode_returns: list[float] = []
        """Returns of the episodes :meth:`learn` finished, in order."""
        self.episode_lengths: list[int] = []
        """Their lengths in environment steps."""
        self.learn_calls = 0
        """Calls of :meth:`learn` so far (the first seeds the environment's reset)."""

    def _build(self, kind: type[Actor] | type[Critic], init_gen: torch.Generator) -> Any:
        """An actor or critic initialised from ``init_gen`` alone, on the agent's device.

        Built on the meta device so that nn.Linear's own init never draws from the
        global torch RNG; then materialised and initialised from ``init_gen`` only.
        """
        cfg = self.config
        options: dict[str, Any] = {}
        if kind is Actor and cfg.actor_update == "inverting_gradients":
            options["output"] = "clip"
        if kind is Critic and cfg.critic_layer_norm:
            options["layer_norm"] = True
        with torch.device("meta"):
            network = kind(
                self.obs_dim, self.action_dim, cfg.hidden_sizes, self._encoder(), **options
            )
        network = network.to_empty(device="cpu")
        if network.encoder is not None:
            network.encoder.reset_parameters(init_gen)
        init_mlp_(network.layers, init_gen)
        for module in network.modules():
            if isinstance(module, nn.LayerNorm):
                module.reset_parameters()  # ones and zeros: draws nothing
        return network.to(self.device)

    def _encoder(self) -> VehicleSetEncoder | None:
        if self.config.encoder == "vehicles":
            return VehicleSetEncoder(
                self.layout.grid_shape, self.config.encoder_width, self.layout.extra_features
            )
        return None

    # ------------------------------------------------------------------ acting
    def _normalise(self, action: np.ndarray) -> np.ndarray:
        scaled = 2.0 * (action - self.action_low) / (self.action_high - self.action_low) - 1.0
        return np.clip(scaled, -1.0, 1.0)

    def _denormalise(self, action: np.ndarray) -> np.ndarray:
        env_action = self.action_low + (action + 1.0) * 0.5 * (self.action_high - self.action_low)
        low, high = self.action_low.astype(np.float32), self.action_high.astype(np.float32)
        return np.clip(env_action.astype(np.float32), low, high).reshape(self.action_shape)

    def _flat_row(self, obs: Any) -> np.ndarray:
        flat = np.asarray(obs, dtype=np.float32).reshape(-1)
        if flat.size != self.obs_dim:
            raise ValueError(f"expected an observation of shape {self.obs_shape}")
        return flat

    def _flat_obs_tensor(self, obs: Any) -> Tensor | SparseRows:
        flat = self._flat_row(obs).reshape(1, -1)
        if self.sparse:
            return SparseRows.from_numpy_row(flat).to(self.device)
        return torch.from_numpy(flat).to(self.device)

    def _policy_action(self, flat: Any) -> np.ndarray:
        """The deterministic policy's normalised action on one flat observation, in float32
        whatever the precision (:mod:`frl.agents.acting`)."""
        if not self.config.guide_residual:
            return actor_action(self.actor, self._flat_row(flat), self.sparse)
        teacher = self._guide_tensor([flat])
        with torch.no_grad():
            policy = self._policy(self.actor, self._flat_obs_tensor(flat), teacher)
        return policy[0].double().cpu().numpy()

    def _autocast(self) -> Any:
        """The context of every forward pass: bf16 autocast under ``precision`` bf16.

        Optimizer steps stay outside it: autocast caches the bf16 copy of each weight
        that needs a gradient until the context exits, and a copy cached before a step
        would be stale after it.
        """
        return autocast(self.device, self.precision)

    def act(self, obs: Any, explore: bool = True) -> np.ndarray:
        """Action for one observation, float32 and within the action bounds.

        With ``explore`` the action is the policy's plus noise (both in normalised units,
        clipped to [-1, 1]); before ``learning_starts`` transitions have been observed it
        comes from the warm-up instead (``DDPGConfig.random_warmup`` and
        ``warmup_policy``), as SB3 and CleanRL act uniformly at random then, so the first
        updates see diverse actions. Without ``explore`` it is the deterministic policy.
        With ``action_repeat`` k > 1 a new action is chosen every k calls and held in
        between: call :meth:`episode_start` at every reset, so that no hold crosses
        episodes.
        """
        cfg = self.config
        if self._hold_left > 0 and self._held_action is not None:
            self._hold_left -= 1
            return self._denormalise(self._held_action)
        if explore and cfg.random_warmup and self.num_env_steps < cfg.learning_starts:
            action = self._warmup_decision(obs)
            self.last_policy_action = np.full(self.action_dim, np.nan)
        else:
            action = self._policy_action(self.layout.flat(obs))
            self.last_policy_action = action
            if explore:
                action = self._explore_stretch(np.clip(action + self.noise(), -1.0, 1.0))
        if cfg.action_repeat > 1:
            self._held_action, self._hold_left = action, cfg.action_repeat - 1
        return self._denormalise(action)

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """``(action, None)`` for one observation or a batch, as Stable-Baselines3's
        ``predict``: float32 actions within the bounds, shaped like the action space (one
        observation) or with a leading batch axis. ``deterministic=False`` adds a draw of
        the exploration noise to each. ``state`` and ``episode_start`` are accepted for
        Stable-Baselines3's signature; DDPG has no recurrent state.

        Raises:
            ValueError: an observation whose shape is neither the space's nor a batch of it.
        """
        batch, batched = self.layout.flat_batch(observation)
        if batched:
            flat = torch.from_numpy(batch).to(self.device)
            teacher = self._guide_tensor(list(batch)) if self.config.guide_residual else None
            with torch.no_grad():  # float32, as acting on one observation
                inputs = SparseRows.from_dense(flat) if self.sparse else flat
                actions = self._policy(self.actor, inputs, teacher).double().cpu().numpy()
        else:
            actions = self._policy_action(batch[0])[None]
        if not deterministic:
            actions = np.clip(actions + np.stack([self.noise() for _ in actions]), -1.0, 1.0)
        env_actions = np.stack([self._denormalise(action) for action in actions])
        return (env_actions if batched else env_actions[0]), None

    def learn(
        self,
        env: Any,
        total_timesteps: int,
        callback: LearnCallback | None = None,
        progress_bar: bool = False,
        tensorboard_log: str | os.PathLike[str] | None = None,
        seed: int | None = None,
    ) -> DDPG:
        """Train on one gymnasium environment for ``total_timesteps`` steps; return the
        agent (Stable-Baselines3's ``model.learn``). See :func:`frl.agents.learn.learn`."""
        return learn(self, env, total_timesteps, callback, progress_bar, tensorboard_log, seed)

    def _explore_stretch(self, action: np.ndarray) -> np.ndarray:
        """``action``, or a uniform one held for a geometric stretch of decisions (mean
        ``warmup_hold_steps``) that starts with chance ``explore_hold_probability`` per
        decision: temporally-extended epsilon-greedy exploration (Dabney et al. 2021)."""
        probability = self.config.explore_hold_probability
        if probability <= 0:
            return action
        if self._stretch_left > 0 and self._stretch_action is not None:
            self._stretch_left -= 1
            return self._stretch_action
        if self._explore_rng.random() < probability:
            self._stretch_action = self._explore_rng.uniform(-1.0, 1.0, size=self.action_dim)
            duration = self._explore_rng.geometric(1.0 / self.config.warmup_hold_steps)
            self._stretch_left = int(duration) - 1
            return self._stretch_action
        return action

    def _policy(self, actor: Actor, inputs: Tensor | SparseRows, teacher: Tensor | None) -> Tensor:
        """``actor``'s actions in [-1, 1]; over the teacher's (``teacher``, normalised)
        under ``guide_residual``."""
        if teacher is None:
            return actor(inputs)
        return residual_action(teacher, actor.preactivation(inputs)).clamp(-1.0, 1.0)

    def set_guide(self, policy: Callable[[Any], Any] | None) -> None:
        """The teacher of a guided agent (``DDPGConfig.guide`` other than ``none``): a
        callable from an observation to an action in the env's units. frl's vehicles
        install :class:`frl.policies.GapAcceptancePolicy` for ``gap_acceptance``, and
        :func:`frl.policies.install_guide` does it for a loaded agent."""
        self._guide = policy

    @property
    def needs_guide(self) -> bool:
        """Whether the agent stores a teacher's actions and has no teacher installed yet."""
        return self.config.guided and self._guide is None

    def _guide_action(self, obs: Any) -> np.ndarray:
        """The teacher's action at ``obs``, normalised to [-1, 1] (float32)."""
        if self._guide is None:
            raise RuntimeError(
                f"guide={self.config.guide!r} needs the teacher: call agent.set_guide(policy) "
                "first (frl's vehicles do; frl.policies.install_guide(agent, env_config) for "
                "a loaded agent)"
            )
        observation = self.layout.unflat(obs)
        if self.layout.parts is None:  # a Box's observation, whether stored flat or not
            observation = np.asarray(observation).reshape(self.obs_shape)
        action = np.asarray(self._guide(observation), dtype=np.float64).reshape(-1)
        return self._normalise(action).astype(np.float32)

    def _guide_tensor(self, observations: list[Any]) -> Tensor:
        """The teacher's normalised actions at ``observations``, a batch on the device."""
        actions = np.stack([self._guide_action(obs) for obs in observations])
        return torch.from_numpy(actions).to(self.device)

    def set_warmup_policy(self, policy: Callable[[np.ndarray], Any] | None) -> None:
        """The driver of the warm-up under ``warmup_policy`` other than ``uniform``: a
        callable from an observation to an action in the env's units (frl's vehicles
        install :class:`frl.policies.GapAcceptancePolicy` for ``gap_acceptance``)."""
        self._warmup_policy = policy

    def _warmup_decision(self, obs: Any) -> np.ndarray:
        """A warm-up action in normalised units (see ``DDPGConfig.warmup_policy``)."""
        cfg = self.config
        if cfg.warmup_policy == "uniform":
            return self._warmup_step()
        if self._warmup_policy is None:
            raise RuntimeError(
                f"warmup_policy={cfg.warmup_policy!r} needs the driver: call "
                "agent.set_warmup_policy(policy) first (frl's vehicles do)"
            )
        rule = np.asarray(self._warmup_policy(obs), dtype=np.float64).reshape(-1)
        perturbation = self._explore_rng.normal(0.0, cfg.noise_sigma, size=self.action_dim)
        return np.clip(self._normalise(rule) + perturbation, -1.0, 1.0)

    def _warmup_step(self) -> np.ndarray:
        """A uniform action, held for a geometric number of steps (mean
        ``warmup_hold_steps``; a fresh one every step at 1)."""
        hold = self.config.warmup_hold_steps
        if self._warmup_action is None or hold <= 1 or self._explore_rng.random() < 1 / hold:
            self._warmup_action = self._explore_rng.uniform(-1.0, 1.0, size=self.action_dim)
        return self._warmup_action

    def reset_noise(self) -> None:
        """Restart the exploration noise (the OU process returns to its mean)."""
        self.noise.reset()

    def episode_start(self) -> None:
        """Call after every ``env.reset()``. A previous episode still pending transitions
        (n-step, or an action still held) was cut off by a time limit: they bootstrap
        from its last state."""
        if self._decision is not None and self._decision.next_obs is not None:
            held = self._decision
            self._store(held.obs, held.action, held.reward, held.next_obs, False, held.steps)
        self._decision = None
        self._held_action, self._hold_left = None, 0
        self._stretch_action, self._stretch_left = None, 0
        for transition in self._n_step.flush():
            self._add(*transition)
        self._warmup_action = None
        self.reset_noise()

    def observe(
        self, obs: Any, action: Any, reward: float, next_obs: Any, terminated: bool
    ) -> None:
        """Store a transition. Pass gymnasium's ``terminated``, not ``terminated or truncated``:
        a time-limit cut-off is not a terminal state and must still bootstrap."""
        obs, next_obs = self.layout.flat(obs), self.layout.flat(next_obs)
        normalised = self._normalise(np.asarray(action, dtype=np.float64).reshape(-1))
        repeat = self.config.action_repeat
        if repeat == 1:
            self._store(obs, normalised, float(reward), next_obs, bool(terminated), 1)
        else:
            if self._decision is None:
                self._decision = _HeldDecision(obs, normalised)
            held = self._decision
            held.reward += self.config.gamma**held.steps * float(reward)
            held.steps += 1
            held.next_obs = next_obs
            if terminated or held.steps == repeat:
                done = bool(terminated)
                self._store(held.obs, held.action, held.reward, next_obs, done, held.steps)
                self._decision = None
        self.num_env_steps += 1

    def _store(
        self, obs: Any, action: np.ndarray, reward: float, next_obs: Any, terminated: bool,
        horizon: int,
    ) -> None:  # fmt: skip
        """Into the buffer, through the n-step accumulator when ``n_step`` > 1."""
        if self.config.n_step == 1:
            self._add(obs, action, reward, next_obs, terminated, horizon)
        else:
            for transition in self._n_step.push(obs, action, reward, next_obs, terminated, horizon):
                self._add(*transition)

    def _add(
        self, obs: Any, action: np.ndarray, reward: float, next_obs: Any, terminated: bool,
        horizon: int,
    ) -> None:  # fmt: skip
        """Into the buffer, with the teacher's actions at both ends when the agent is guided."""
        guide: tuple[np.ndarray, ...] = ()
        if self.config.guided:
            guide = (self._guide_action(obs), self._guide_action(next_obs))
        self.buffer.add(obs, action, reward, next_obs, terminated, horizon, *guide)

    # ---------------------------------------------------------------- learning
    def update(self) -> dict[str, float]:
        """Take ``gradient_steps`` gradient steps if one is due; return the last losses.

        Due when at least ``learning_starts`` transitions were observed, the buffer holds a
        batch, and ``num_env_steps`` is a multiple of ``train_freq``. Otherwise ``{}``.
        """
        cfg = self.config
        if (
            self.num_env_steps < cfg.learning_starts
            or len(self.buffer) < cfg.batch_size
            or self.num_env_steps % cfg.train_freq != 0
        ):
            return {}
        for _ in range(cfg.gradient_steps):
            lap = cfg.replay == "lap"
            if lap:
                slots = self.buffer.sample_slots_prioritized(cfg.batch_size)
            else:
                slots = self.buffer.sample_slots_ends(cfg.batch_size, cfg.terminal_fraction)
            batch = self.buffer.gather(slots, sparse=self.sparse, device=self.device)
            stats = self._train_step(batch)
            if lap:
                td_abs = stats.pop("td_abs").cpu().numpy()
                priorities = lap_priority(td_abs, cfg.lap_alpha, cfg.lap_min_priority)
                self.buffer.set_priorities(slots, priorities)
            self.num_updates += 1
        return {name: value.item() for name, value in stats.items()}

    def _train_step(self, batch: Batch) -> dict[str, Tensor]:
        cfg = self.config
        with self._autocast():
            with torch.no_grad():
                target_policy = self._policy(
                    self.actor_target, batch.next_obs, self._residual_base(batch.next_guide_actions)
                )
                next_action = self._smoothed(target_policy)
                next_q = self.critic_target(batch.next_obs, next_action)
                if self.critic2_target is not None:
                    other = self.critic2_target(batch.next_obs, next_action)
                    next_q = torch.minimum(next_q, other)
            q_values = [critic(batch.obs, batch.actions) for critic in self._critics]
        # The outputs are float32 (frl.agents.precision.float32_layer): the target and the
        # losses below are computed in float32 whatever the precision.
        with torch.no_grad():
            # gamma**k for an n-step transition of k steps (k = 1: the one-step target).
            multi_step = cfg.n_step > 1 or cfg.action_repeat > 1
            discount = cfg.gamma**batch.horizons if multi_step else cfg.gamma
            target_q = td_target(batch.rewards, batch.terminated, next_q, discount)
        critic_loss = self._critic_loss(q_values[0], target_q)
        for q_other in q_values[1:]:
            critic_loss = critic_loss + self._critic_loss(q_other, target_q)
        self.critic_optimizer.zero_grad(set_to_none=True)
        critic_loss.backward()
        if self._proximal_critic:
            self._add_proximal_gradient(self._proximal_critic)
        self.critic_optimizer.step()
        q = q_values[0].detach()
        td_abs = (q - target_q).abs()
        stats = {
            "critic_loss": critic_loss.detach(),
            "q_mean": q.mean(),
            "td_error": td_abs.mean(),
        }
        if cfg.replay == "lap":  # per transition, the larger critic's error (TD7)
            for q_other in q_values[1:]:
                td_abs = torch.maximum(td_abs, (q_other.detach() - target_q).abs())
            stats["td_abs"] = td_abs
        # TD3's delayed updates: the actor and the targets move every policy_delay-th step.
        if self.num_updates % cfg.policy_delay == 0:
            stats.update(self._actor_step(batch))
            soft_update(self._target_params, self._online_params, cfg.tau)
        return stats

    def _critic_loss(self, q: Tensor, target: Tensor) -> Tensor:
        """The squared TD error (Table II), or LAP's Huber loss under ``replay=lap``."""
        if self.config.replay == "lap":
            return lap_critic_loss(q, target, self.config.lap_min_priority)
        return F.mse_loss(q, target)

    def _residual_base(self, guide_actions: Tensor | None) -> Tensor | None:
        """The teacher's actions a residual actor adds to; None for any other actor."""
        return guide_actions if self.config.guide_residual else None

    def _imitation_weight(self) -> float:
        """The imitation term's weight now (``guide_weight``, decayed)."""
        cfg = self.config
        return guide_weight_at(cfg.guide_weight, cfg.guide_decay_steps, self.num_env_steps)

    def _imitation(
        self, batch: Batch, preactivation: Tensor, q_actor: Tensor
    ) -> tuple[Tensor, Tensor] | None:
        """The weighted imitation term on the actor's (unbounded) action and the share of
        the batch it applies to; None when it is off.

        The Q-filter compares the critic's value of the teacher's action with its value of
        the actor's (``q_actor``, the clipped action), both without gradients.
        """
        weight = self._imitation_weight()
        if weight <= 0 or batch.guide_actions is None:
            return None
        teacher = batch.guide_actions
        cfg = self.config
        if cfg.guide_filter in ("q", "q_lower"):
            with torch.no_grad(), self._autocast():
                q_teacher = self.critic(batch.obs, teacher)
            mask = q_filter(q_teacher, q_actor.detach(), cfg.guide_filter_margin)
            if cfg.guide_filter == "q_lower":
                actor_action = preactivation.detach().float().clamp(-1.0, 1.0)
                mask = lower_only(mask, actor_action, teacher)
        else:
            mask = torch.ones(teacher.shape[0], device=teacher.device)
        loss = weight * imitation_loss(preactivation.float(), teacher, mask)
        return loss, mask.mean()

    def _smoothed(self, action: Tensor) -> Tensor:
        """TD3's target policy smoothing (``target_noise`` > 0), else ``action`` itself."""
        cfg = self.config
        if cfg.target_noise <= 0:
            return action
        noise = torch.randn(
            action.shape, generator=self._target_noise_gen, device=action.device
        ).mul_(cfg.target_noise)
        noise = noise.clamp_(-cfg.target_noise_clip, cfg.target_noise_clip)
        return (action.float() + noise).clamp_(-1.0, 1.0)

    def _actor_step(self, batch: Batch) -> dict[str, Tensor]:
        """One actor update through the first critic: the detached loss -Q, and the
        imitation term with the share of the batch it reached when the agent is guided."""
        cfg = self.config
        # Freeze the critic so backward computes only what the actor needs: no critic
        # weight gradients (and none for its sparse first layer), just dQ/da.
        self.critic.requires_grad_(False)
        try:
            if cfg.actor_update == "inverting_gradients":
                loss, preactivation, q_policy = self._inverting_gradients_loss(batch)
            else:
                loss, preactivation, q_policy = self._deterministic_policy_loss(batch)
            stats = {"actor_loss": -q_policy.detach().mean()}
            imitation = self._imitation(batch, preactivation, q_policy)
            if imitation is not None:
                loss = loss + imitation[0]
                stats["imitation_loss"], stats["guide_share"] = imitation[0].detach(), imitation[1]
            self.actor_optimizer.zero_grad(set_to_none=True)
            loss.backward()
        finally:
            self.critic.requires_grad_(True)
        if self._proximal_actor:
            self._add_proximal_gradient(self._proximal_actor)
        self.actor_optimizer.step()
        return stats

    def _deterministic_policy_loss(self, batch: Batch) -> tuple[Tensor, Tensor, Tensor]:
        """DDPG's actor loss -Q(s, tanh(p)) (plus the pre-tanh penalty), with ``p`` and Q."""
        cfg = self.config
        with self._autocast():
            preactivation = self.actor.preactivation(batch.obs)
            q_policy = self.critic(batch.obs, torch.tanh(preactivation))
        loss = -q_policy.mean()
        if cfg.preactivation_l2 > 0:
            loss = loss + cfg.preactivation_l2 * preactivation.square().mean()
        return loss, preactivation, q_policy

    def _inverting_gradients_loss(self, batch: Batch) -> tuple[Tensor, Tensor, Tensor]:
        """A surrogate loss whose gradient is the actor's by inverting gradients (Hausknecht
        and Stone 2016), with the unbounded action ``p`` and Q at the clipped one.

        dQ/da at the clipped action is scaled by ``(1 - p) / 2`` where it asks for more
        and ``(p + 1) / 2`` where it asks for less: it fades as the output nears the bound
        it points to and turns round beyond it, so the output stays within [-1, 1] and can
        always come back. A residual actor's ``p`` is the teacher's action plus its own.
        """
        with self._autocast():
            preactivation = self.actor.preactivation(batch.obs)
        base = self._residual_base(batch.guide_actions)
        if base is not None:
            preactivation = residual_action(base, preactivation)
        action = preactivation.detach().clamp(-1.0, 1.0).requires_grad_(True)
        with self._autocast():
            q_policy = self.critic(batch.obs, action)
        (dq_da,) = torch.autograd.grad(q_policy.sum(), action)
        room = preactivation.detach()
        scale = torch.where(dq_da > 0, (1.0 - room) / 2.0, (room + 1.0) / 2.0)
        surrogate = -(dq_da * scale * preactivation).sum() / preactivation.shape[0]
        return surrogate, preactivation, q_policy

    def critic_values(self, observations: Any, actions: Any) -> np.ndarray:
        """Q(s, a) of the online critic for a batch of observations (an array, or for a
        Dict space a sequence of observations) and env-unit actions."""
        if self.layout.parts is not None and not isinstance(observations, np.ndarray):
            observations = [self.layout.flat(o) for o in observations]
        obs = np.asarray(observations, dtype=np.float32).reshape(-1, self.obs_dim)
        normalised = self._normalise(
            np.asarray(actions, dtype=np.float64).reshape(len(obs), -1)
        ).astype(np.float32)
        x = torch.from_numpy(obs)
        inputs = SparseRows.from_dense(x).to(self.device) if self.sparse else x.to(self.device)
        with torch.no_grad(), self._autocast():
            q = self.critic(inputs, torch.from_numpy(normalised).to(self.device))
        return q.reshape(-1).double().cpu().numpy()

    # ---------------------------------------------------------- federated state
    def _networks(self) -> dict[str, nn.Module]:
        networks = {
            "actor": self.actor,
            "critic": self.critic,
            "actor_target": self.actor_target,
            "critic_target": self.critic_target,
            "critic2": self.critic2,
            "critic2_target": self.critic2_target,
        }
        return {name: net for name, net in networks.items() if net is not None}

    @property
    def federated_keys(self) -> tuple[str, ...]:
        """Keys of :meth:`federated_state`, in a stable order."""
        return tuple(
            f"{prefix}.{name}"
            for prefix, net in self._networks().items()
            for name in net.state_dict()
        )

    def federated_state(self) -> dict[str, Tensor]:
        """Detached contiguous CPU copies of all network parameters (online and target).

        Keys look like ``actor.layers.0.weight`` or ``critic_target.layers.4.bias``; see
        :func:`is_target_key`. Optimizer moments, the replay buffer and the noise stay
        private to the agent.
        """
        return {
            f"{prefix}.{name}": tensor.detach().to(
                "cpu", memory_format=torch.contiguous_format, copy=True
            )
            for prefix, net in self._networks().items()
            for name, tensor in net.state_dict().items()
        }

    def load_federated_state(self, state: dict[str, Tensor]) -> None:
        """Copy a :meth:`federated_state`-shaped dict into the networks.

        Strict: a missing or unexpected key, or a shape mismatch, raises ``ValueError``
        naming the key, and nothing is modified.
        """
        expected = {
            f"{prefix}.{name}": tensor
            for prefix, net in self._networks().items()
            for name, tensor in net.state_dict().items()
        }
        missing = [key for key in expected if key not in state]
        if missing:
            raise ValueError(f"federated state lacks key {missing[0]!r} ({len(missing)} missing)")
        unexpected = [key for key in state if key not in expected]
        if unexpected:
            raise ValueError(f"federated state has unexpected key {unexpected[0]!r}")
        for key, tensor in expected.items():
            value = state[key]
            if not isinstance(value, Tensor) or value.shape != tensor.shape:
                shape = tuple(value.shape) if isinstance(value, Tensor) else type(value).__name__
                raise ValueError(f"{key!r}: expected shape {tuple(tensor.shape)}, got {shape}")
        with torch.no_grad():
            for key, tensor in expected.items():
                tensor.copy_(state[key])

    def set_proximal_anchor(self, mu: float) -> None:
        """FedProx (Li et al. 2020): from now on each update adds mu/2 ||w - w_anchor||^2 to
        the critic and actor losses, w_anchor the online networks as they are now (the
        global model just loaded). ``mu`` = 0 removes the term."""
        if not mu >= 0:
            raise ValueError(f"proximal mu must be >= 0, got {mu!r}")

        def anchored(nets: list[nn.Module]) -> list[tuple[Tensor, Tensor]]:
            return [(p, p.detach().clone()) for net in nets for p in net.parameters()]

        self._proximal_mu = float(mu)
        self._proximal_actor = anchored([self.actor]) if mu else []
        self._proximal_critic = anchored(self._critics) if mu else []

    def _add_proximal_gradient(self, anchored: list[tuple[Tensor, Tensor]]) -> None:
        """The proximal term's gradient, mu (w - w_anchor), added to each parameter's."""
        with torch.no_grad():
            for param, anchor in anchored:
                pull = (param - anchor).mul_(self._proximal_mu)
                if param.grad is None:
                    param.grad = pull
                else:
                    param.grad.add_(pull)

    def sync_targets(self) -> None:
        """Hard-copy the online networks into the targets (e.g. after FedAvg of onlines)."""
        hard_update(self._target_params, self._online_params)

    # -------------------------------------------------------------- checkpoints
    def _spaces_record(self) -> dict[str, Any]:
        return {
            "obs_shape": list(self.obs_shape),
            "obs_parts": self.layout.record(),
            "action_shape": list(self.action_shape),
            "action_low": torch.from_numpy(self.action_low.copy()),
            "action_high": torch.from_numpy(self.action_high.copy()),
        }

    def save(self, path: str | os.PathLike[str], include_buffer: bool = False) -> None:
        """Write networks, optimizers, noise, counters and generators (and the buffer).

        The file is written atomically and loads with ``torch.load(weights_only=True)``.
        """
        write_checkpoint(
            {
                "config": self.config.to_dict(),
                "seed": self.seed,
                "spaces": self._spaces_record(),
                "networks": {
                    name: {k: v.detach().cpu() for k, v in net.state_dict().items()}
                    for name, net in self._networks().items()
                },
                "optimizers": {
                    "actor": self.actor_optimizer.state_dict(),
                    "critic": self.critic_optimizer.state_dict(),
                },
                "noise": self.noise.state_dict(),
                "n_step": self._n_step.state_dict(),
                "rngs": {
                    "explore": generator_state(self._explore_rng),
                    "buffer": generator_state(self.buffer.rng),
                    "target_noise": self._target_noise_gen.get_state(),
                },
                "counters": {"num_env_steps": self.num_env_steps, "num_updates": self.num_updates},
                "warmup_action": None
                if self._warmup_action is None
                else torch.from_numpy(self._warmup_action.copy()),
                "held": self._held_state(),
                "buffer": self.buffer.state_dict() if include_buffer else None,
            },
            path,
        )

    def restore(self, path: str | os.PathLike[str]) -> None:
        """Restore a :meth:`save` file into this agent (same config and spaces): exact
        resume. :meth:`load` builds a new agent from a file instead.

        Without a saved buffer the agent resumes with an empty buffer.

        Raises:
            CheckpointError: unreadable or foreign file, or one saved by an agent with a
                different config, spaces or network shapes (checked before anything is
                modified).
        """
        data = read_checkpoint(path)
        try:
            self._check_compatible(data)
            for name, net in self._networks().items():
                _check_state_dict(data["networks"][name], net.state_dict(), name)
        except (KeyError, TypeError, AttributeError) as error:
            raise CheckpointError(f"{path}: malformed checkpoint ({error!r})") from error
        try:
            for name, net in self._networks().items():
                net.load_state_dict(data["networks"][name])
            self.actor_optimizer.load_state_dict(data["optimizers"]["actor"])
            self.critic_optimizer.load_state_dict(data["optimizers"]["critic"])
            self.noise.load_state_dict(data["noise"])
            self._n_step.load_state_dict(data.get("n_step", {}))
            held = data.get("warmup_action")
            self._warmup_action = None if held is None else held.numpy().astype(np.float64)
            self._load_held_state(data.get("held"))
            if data["buffer"] is not None:
                self.buffer.load_state_dict(data["buffer"])
            else:
                self.buffer.pos = self.buffer.size = 0
            set_generator_state(self._explore_rng, data["rngs"]["explore"])
            set_generator_state(self.buffer.rng, data["rngs"]["buffer"])
            if "target_noise" in data["rngs"]:  # absent in checkpoints from before TD3
                self._target_noise_gen.set_state(data["rngs"]["target_noise"])
            self.num_env_steps = int(data["counters"]["num_env_steps"])
            self.num_updates = int(data["counters"]["num_updates"])
        except (KeyError, TypeError, AttributeError, ValueError, RuntimeError) as error:
            raise CheckpointError(f"{path}: malformed checkpoint ({error!r})") from error

    def _held_state(self) -> dict[str, Any] | None:
        """The held action and its decision so far (``action_repeat`` > 1), and the held
        exploration stretch, as tensors."""
        if self._held_action is None and self._decision is None and self._stretch_action is None:
            return None
        decision = self._decision
        return {
            "stretch_action": None
            if self._stretch_action is None
            else torch.from_numpy(self._stretch_action.copy()),
            "stretch_left": self._stretch_left,
            "action": None
            if self._held_action is None
            else torch.from_numpy(self._held_action.copy()),
            "left": self._hold_left,
            "decision": None
            if decision is None or decision.next_obs is None
            else {
                "obs": torch.from_numpy(np.asarray(decision.obs, np.float32).copy()),
                "action": torch.from_numpy(decision.action.copy()),
                "reward": decision.reward,
                "steps": decision.steps,
                "next_obs": torch.from_numpy(np.asarray(decision.next_obs, np.float32).copy()),
            },
        }

    def _load_held_state(self, state: dict[str, Any] | None) -> None:
        self._held_action, self._hold_left, self._decision = None, 0, None
        self._stretch_action, self._stretch_left = None, 0
        if state is None:
            return
        if state.get("stretch_action") is not None:
            self._stretch_action = state["stretch_action"].numpy().astype(np.float64)
        self._stretch_left = int(state.get("stretch_left", 0))
        if state["action"] is not None:
            self._held_action = state["action"].numpy().astype(np.float64)
        self._hold_left = int(state["left"])
        decision = state["decision"]
        if decision is not None:
            self._decision = _HeldDecision(
                decision["obs"].numpy(),
                decision["action"].numpy().astype(np.float64),
                float(decision["reward"]),
                int(decision["steps"]),
                decision["next_obs"].numpy(),
            )

    def _check_compatible(self, data: dict[str, Any]) -> None:
        # Keys added to DDPGConfig since a checkpoint was written read as what it ran with.
        saved = DDPGConfig.from_dict(data["config"]).to_dict()
        mine = self.config.to_dict()
        differing = sorted(k for k in set(saved) | set(mine) if saved.get(k) != mine.get(k))
        if differing:
            raise CheckpointError(f"checkpoint config differs from this agent's in {differing}")
        spaces_saved, spaces_mine = data["spaces"], self._spaces_record()
        if spaces_saved.get("obs_parts") != spaces_mine["obs_parts"]:
            raise CheckpointError(
                f"checkpoint observation parts {spaces_saved.get('obs_parts')} != "
                f"{spaces_mine['obs_parts']}"
            )
        for key in ("obs_shape", "action_shape"):
            if list(spaces_saved[key]) != spaces_mine[key]:
                raise CheckpointError(f"checkpoint {key} {spaces_saved[key]} != {spaces_mine[key]}")
        for key in ("action_low", "action_high"):
            if not torch.equal(spaces_saved[key], spaces_mine[key]):
                raise CheckpointError(f"checkpoint {key} differs from this agent's action space")

    @classmethod
    def from_checkpoint(
        cls,
        path: str | os.PathLike[str],
        observation_space: spaces.Box | spaces.Dict | None = None,
        action_space: spaces.Box | None = None,
        device: str | torch.device = "cpu",
    ) -> DDPG:
        """A new agent built with the checkpoint's config and seed, then :meth:`restore`-d.
        Spaces left out are rebuilt from the file (the observation bounds as unbounded)."""
        data = read_checkpoint(path)
        try:
            config = DDPGConfig.from_dict(data["config"])
            seed = int(data["seed"])
        except (KeyError, TypeError, ValueError) as error:
            raise CheckpointError(f"{path}: malformed checkpoint config ({error!r})") from error
        if observation_space is None or action_space is None:
            saved_observation, saved_action = _spaces_of(data, path)
            observation_space = observation_space or saved_observation
            action_space = action_space or saved_action
        agent = cls(observation_space, action_space, config, seed=seed, device=device)
        agent.restore(path)
        return agent

    @_class_only
    def load(cls, path: str | os.PathLike[str], device: str | torch.device = "cpu") -> DDPG:
        """A new agent from a :meth:`save` file, a run's ``models/*.pt`` included: its
        config, seed and spaces come from the file (``DDPG.load(path)``, as in
        Stable-Baselines3). Checkpoints load with ``weights_only=True``.

        Raises:
            CheckpointError: unreadable, foreign or malformed file.
        """
        return cls.from_checkpoint(path, device=device)


def _check_state_dict(saved: Any, current: dict[str, Tensor], prefix: str) -> None:
    if not isinstance(saved, dict) or set(saved) != set(current):
        raise CheckpointError(f"checkpoint {prefix} parameters do not match this agent's")
    for key, tensor in current.items():
        if not isinstance(saved[key], Tensor) or saved[key].shape != tensor.shape:
            raise CheckpointError(f"checkpoint {prefix}.{key} has the wrong shape")


def _spaces_of(
    data: dict[str, Any], path: str | os.PathLike[str]
) -> tuple[spaces.Box | spaces.Dict, spaces.Box]:
    """The observation and action spaces a checkpoint records."""
    try:
        record = data["spaces"]
        observation = space_from_record(record["obs_shape"], record.get("obs_parts"))
        shape = tuple(record["action_shape"])
        low = record["action_low"].numpy().astype(np.float32).reshape(shape)
        high = record["action_high"].numpy().astype(np.float32).reshape(shape)
        return observation, spaces.Box(low, high, shape, dtype=np.float32)
    except (KeyError, TypeError, AttributeError, ValueError) as error:
        raise CheckpointError(f"{path}: malformed checkpoint spaces ({error!r})") from error
