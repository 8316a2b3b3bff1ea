"""DDPG (Lillicrap et al. 2016) for gymnasium Box spaces, with a federated-state interface.

The agent wires together parts that each do one thing: the four networks
(:class:`frl.agents.networks.ActorCritic`), the explorer (warm-up and noise,
:mod:`frl.agents.explorer`), the transition writer (n-step transitions and teacher labels,
:mod:`frl.agents.transitions`) into the replay buffer, acting on one observation
(:mod:`frl.agents.acting`), the losses' maths (:mod:`frl.agents.functional`,
:mod:`frl.agents.guide`) and checkpoints (:mod:`frl.agents.checkpoint`). What is left
here is the algorithm: act, observe, and the update in :meth:`DDPG._train_step`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from gymnasium import spaces
from torch import Tensor, nn

from frl.agents import checkpoint
from frl.agents.acting import actor_action
from frl.agents.config import DDPGConfig
from frl.agents.explorer import Explorer
from frl.agents.functional import (
    add_proximal_gradient,
    hard_update,
    inverting_gradients_loss,
    soft_update,
    td_target,
)
from frl.agents.guide import guide_weight_at, imitation_loss, lower_only, q_filter
from frl.agents.learn import LearnCallback, learn
from frl.agents.networks import NETWORK_NAMES, Actor, ActorCritic, Critic, init_mlp_
from frl.agents.observations import ObservationLayout
from frl.agents.precision import autocast, resolve_precision
from frl.agents.replay_buffer import Batch, ReplayBuffer
from frl.agents.sparse_linear import SparseRows
from frl.agents.transitions import TransitionWriter
from frl.agents.vehicle_encoder import VehicleSetEncoder

Space = spaces.Box | spaces.Dict
"""The observation spaces an agent reads."""
_TARGET_PREFIXES = tuple(f"{name}." for name in NETWORK_NAMES if name.endswith("_target"))


def is_target_key(name: str) -> bool:
    """Whether a federated-state key belongs to a target network."""
    return name.startswith(_TARGET_PREFIXES)


def _make_adam(params: list[nn.Parameter], lr: float, device: torch.device) -> torch.optim.Adam:
    # The fused kernel updates all parameters in one pass; on CPU it exists since torch 2.4.
    try:
        return torch.optim.Adam(params, lr=lr, fused=True)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.Adam(params, lr=lr, foreach=device.type != "cpu" or None)


class DDPG:
    """Deep Deterministic Policy Gradient agent for a Box observation and a Box action space.

    Args:
        observation_space: any Box, or a Dict of Boxes (:mod:`frl.agents.observations`);
            observations are flattened. Large ones (``DDPGConfig.sparse_input``) take the
            sparse first-layer path and compact replay.
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
    Stable-Baselines3. Loops of their own call :meth:`episode_start` at each reset,
    :meth:`act`, :meth:`observe` with the transition and :meth:`update` once per step
    (:func:`frl.agents.learn.training_step` does all three).
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
        self.config = cfg = config if config is not None else DDPGConfig()
        self.seed, self.device = int(seed), torch.device(device)
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
        """What updates compute in: ``float32`` or ``bf16`` (acting is always float32)."""

        init_seq, noise_seq, buffer_seq, explore_seq = np.random.SeedSequence(self.seed).spawn(4)
        if init_seed is not None:
            init_seq = np.random.SeedSequence(int(init_seed))
        init_gen = torch.Generator().manual_seed(int(init_seq.generate_state(1, np.uint64)[0]))
        self.networks = ActorCritic(self._build(Actor, init_gen), self._build(Critic, init_gen))
        nets = self.networks
        self.actor, self.critic = nets.actor, nets.critic
        self.actor_target, self.critic_target = nets.actor_target, nets.critic_target
        self.actor_optimizer = _make_adam(list(self.actor.parameters()), cfg.actor_lr, self.device)
        self.critic_optimizer = _make_adam(
            list(self.critic.parameters()), cfg.critic_lr, self.device
        )
        noise_rng, warmup_rng = np.random.default_rng(noise_seq), np.random.default_rng(explore_seq)
        self.explorer = Explorer(cfg, self.action_dim, noise_rng, warmup_rng)
        # Compact storage whenever the observation is large, even for a dense network.
        compact = cfg.sparse_input is True or self.obs_dim >= cfg.sparse_min_features
        self.buffer = ReplayBuffer(
            cfg.buffer_size, self.obs_shape, self.action_dim, np.random.default_rng(buffer_seq),
            sparse=compact, sparse_width=cfg.sparse_capacity, guided=cfg.guided,
        )  # fmt: skip
        teacher = self._teacher_action if cfg.guided else None
        self.writer = TransitionWriter(self.buffer, cfg.n_step, cfg.gamma, teacher)
        self._guide: Callable[[Any], Any] | None = None
        self._proximal_mu = 0.0
        # FedProx: (parameter, the global model's value it is pulled towards).
        self._proximal_actor: list[tuple[Tensor, Tensor]] = []
        self._proximal_critic: list[tuple[Tensor, Tensor]] = []
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
        encoder = None
        if cfg.encoder == "vehicles":
            grid, extra = self.layout.grid_shape, self.layout.extra_features
            encoder = VehicleSetEncoder(grid, cfg.encoder_width, extra)
        options = {"output": "clip"} if kind is Actor and cfg.actor_update != "tanh" else {}
        with torch.device("meta"):
            network = kind(self.obs_dim, self.action_dim, cfg.hidden_sizes, encoder, **options)
        network = network.to_empty(device="cpu")
        if network.encoder is not None:
            network.encoder.reset_parameters(init_gen)
        init_mlp_(network.layers, init_gen)
        return network.to(self.device)

    # ------------------------------------------------------------------ acting
    def _normalise(self, action: np.ndarray) -> np.ndarray:
        scaled = 2.0 * (action - self.action_low) / (self.action_high - self.action_low) - 1.0
        return np.clip(scaled, -1.0, 1.0)

    def _denormalise(self, action: np.ndarray) -> np.ndarray:
        env_action = self.action_low + (action + 1.0) * 0.5 * (self.action_high - self.action_low)
        low, high = self.action_low.astype(np.float32), self.action_high.astype(np.float32)
        return np.clip(env_action.astype(np.float32), low, high).reshape(self.action_shape)

    def _autocast(self) -> Any:
        """The context of the update's forward passes: bf16 autocast under ``precision``
        bf16. Optimizer steps stay outside it: autocast caches the bf16 copy of each
        weight that needs a gradient until the context exits, and a copy cached before a
        step would be stale after it."""
        return autocast(self.device, self.precision)

    def _policy_action(self, flat: Any) -> np.ndarray:
        """The deterministic policy's normalised action on one flat observation."""
        flat = np.asarray(flat, dtype=np.float32).reshape(-1)
        if flat.size != self.obs_dim:
            raise ValueError(f"expected an observation of shape {self.obs_shape}")
        return actor_action(self.actor, flat, self.sparse)

    def act(self, obs: Any, explore: bool = True) -> np.ndarray:
        """Action for one observation, float32 and within the action bounds.

        With ``explore`` it is the explorer's (:class:`frl.agents.explorer.Explorer`): a
        held uniform action during the warm-up, then the policy's plus noise. Without it,
        the deterministic policy.
        """
        if explore and self.explorer.in_warmup(self.num_env_steps):
            self.last_policy_action = np.full(self.action_dim, np.nan)
            return self._denormalise(self.explorer.warmup_action())
        action = self.last_policy_action = self._policy_action(self.layout.flat(obs))
        return self._denormalise(self.explorer.noisy(action) if explore else action)

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:  # fmt: skip
        """``(action, None)`` for one observation or a batch, as Stable-Baselines3's
        ``predict``: float32 actions within the bounds, shaped like the action space (one
        observation) or with a leading batch axis. ``deterministic=False`` adds what the
        exploration noise would add next, from a copy of it: ``predict`` never changes
        the agent. ``state`` and ``episode_start`` are accepted for Stable-Baselines3's
        signature; DDPG has no recurrent state.

        Raises:
            ValueError: an observation whose shape is neither the space's nor a batch of it.
        """
        batch, batched = self.layout.flat_batch(observation)
        if batched:
            flat = torch.from_numpy(batch).to(self.device)
            with torch.no_grad():  # float32, as acting on one observation
                actions = self.actor(SparseRows.from_dense(flat) if self.sparse else flat)
            actions = actions.double().cpu().numpy()
        else:
            actions = self._policy_action(batch[0])[None]
        if not deterministic:
            actions = self.explorer.noisy_copies(actions)
        env_actions = np.stack([self._denormalise(action) for action in actions])
        return (env_actions if batched else env_actions[0]), None

    def learn(
        self, env: Any, total_timesteps: int, callback: LearnCallback | None = None,
        progress_bar: bool = False, tensorboard_log: str | os.PathLike[str] | None = None,
        seed: int | None = None,
    ) -> DDPG:  # fmt: skip
        """Train on one gymnasium environment for ``total_timesteps`` steps; return the
        agent (Stable-Baselines3's ``model.learn``). See :func:`frl.agents.learn.learn`."""
        return learn(self, env, total_timesteps, callback, progress_bar, tensorboard_log, seed)

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

    def _teacher_action(self, flat: np.ndarray) -> np.ndarray:
        """The teacher's action at a flat observation, normalised to [-1, 1] (float32)."""
        if self._guide is None:
            raise RuntimeError(
                f"guide={self.config.guide!r} needs the teacher: call agent.set_guide(policy) "
                "first (frl's vehicles do; frl.policies.install_guide(agent, env_config) for "
                "a loaded agent)"
            )
        observation = self.layout.unflat(flat)
        if self.layout.parts is None:  # a Box's observation, whether stored flat or not
            observation = np.asarray(observation).reshape(self.obs_shape)
        action = np.asarray(self._guide(observation), dtype=np.float64).reshape(-1)
        return self._normalise(action).astype(np.float32)

    def episode_start(self) -> None:
        """Call after every ``env.reset()``. The previous episode's pending n-step steps,
        cut off by a time limit, bootstrap from its last state."""
        self.writer.end_episode()
        self.explorer.episode_start()

    def observe(
        self, obs: Any, action: Any, reward: float, next_obs: Any, terminated: bool
    ) -> None:
        """Store a transition. Pass gymnasium's ``terminated``, not ``terminated or truncated``:
        a time-limit cut-off is not a terminal state and must still bootstrap."""
        normalised = self._normalise(np.asarray(action, dtype=np.float64).reshape(-1))
        flat, next_flat = self.layout.flat(obs), self.layout.flat(next_obs)
        self.writer.write(flat, normalised, float(reward), next_flat, bool(terminated))
        self.num_env_steps += 1

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
            slots = self.buffer.sample_slots(cfg.batch_size)
            stats = self._train_step(self.buffer.gather(slots, self.sparse, self.device))
            self.num_updates += 1
        return {name: value.item() for name, value in stats.items()}

    def _train_step(self, batch: Batch) -> dict[str, Tensor]:
        """One DDPG update (Lillicrap et al. 2016, Algorithm 1) on a sampled batch."""
        cfg, nets = self.config, self.networks
        # Critic: squared error to the n-step TD target of the target networks. Q-values
        # are float32 (precision.float32_layer), and so are the target and the losses.
        with self._autocast(), torch.no_grad():
            next_q = nets.critic_target(batch.next_obs, nets.actor_target(batch.next_obs))
        with self._autocast():
            q = nets.critic(batch.obs, batch.actions)
        discount = cfg.gamma**batch.horizons if cfg.n_step > 1 else cfg.gamma
        target_q = td_target(batch.rewards, batch.terminated, next_q, discount)
        critic_loss = F.mse_loss(q, target_q)
        self._descend(self.critic_optimizer, critic_loss, self._proximal_critic)
        q = q.detach()
        stats = {
            "critic_loss": critic_loss.detach(),
            "q_mean": q.mean(),
            "td_error": (q - target_q).abs().mean(),
        }
        # Actor: up the critic's gradient at its own action. The critic is frozen, so
        # backward computes dQ/da and no critic weight gradient.
        nets.critic.requires_grad_(False)
        try:
            with self._autocast():
                preactivation = nets.actor.preactivation(batch.obs)
            actor_loss, q_policy = self._actor_loss(batch, preactivation)
            stats["actor_loss"] = -q_policy.detach().mean()
            imitation = self._imitation(batch, preactivation, q_policy)
            if imitation is not None:  # a guided agent's pull towards its teacher
                actor_loss = actor_loss + imitation[0]
                stats["imitation_loss"], stats["guide_share"] = imitation[0].detach(), imitation[1]
            self._descend(self.actor_optimizer, actor_loss, self._proximal_actor)
        finally:
            nets.critic.requires_grad_(True)
        # Targets: follow the online networks by Polyak averaging.
        soft_update(nets.target_parameters(), nets.online_parameters(), cfg.tau)
        return stats

    def _actor_loss(self, batch: Batch, preactivation: Tensor) -> tuple[Tensor, Tensor]:
        """The actor's loss from its unbounded action ``p``, and Q at the action taken:
        -Q(s, tanh(p)) (``actor_update=tanh``, with the pre-tanh penalty), or the
        inverting-gradients surrogate at the clipped action."""
        cfg, critic = self.config, self.networks.critic
        if cfg.actor_update == "tanh":
            with self._autocast():
                q_policy = critic(batch.obs, torch.tanh(preactivation))
            loss = -q_policy.mean()
            if cfg.preactivation_l2 > 0:
                loss = loss + cfg.preactivation_l2 * preactivation.square().mean()
            return loss, q_policy
        action = preactivation.detach().clamp(-1.0, 1.0).requires_grad_(True)
        with self._autocast():
            q_policy = critic(batch.obs, action)
        (dq_da,) = torch.autograd.grad(q_policy.sum(), action)
        return inverting_gradients_loss(preactivation, dq_da), q_policy

    def _imitation(
        self, batch: Batch, preactivation: Tensor, q_actor: Tensor
    ) -> tuple[Tensor, Tensor] | None:
        """The weighted imitation term on the actor's unbounded action and the share of the
        batch it applies to (Q-filtered as ``guide_filter`` says); None when it is off."""
        cfg = self.config
        weight = guide_weight_at(cfg.guide_weight, cfg.guide_decay_steps, self.num_env_steps)
        teacher = batch.guide_actions
        if weight <= 0 or teacher is None:
            return None
        mask = torch.ones(teacher.shape[0], device=teacher.device)
        if cfg.guide_filter in ("q", "q_lower"):
            with torch.no_grad(), self._autocast():
                q_teacher = self.networks.critic(batch.obs, teacher)
            mask = q_filter(q_teacher, q_actor.detach(), cfg.guide_filter_margin)
            if cfg.guide_filter == "q_lower":
                actor_action = preactivation.detach().float().clamp(-1.0, 1.0)
                mask = lower_only(mask, actor_action, teacher)
        loss = weight * imitation_loss(preactivation.float(), teacher, mask)
        return loss, mask.mean()

    def _descend(
        self, optimizer: torch.optim.Optimizer, loss: Tensor, anchored: list[tuple[Tensor, Tensor]]
    ) -> None:
        """One optimizer step down ``loss`` (plus FedProx's pull to ``anchored``)."""
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if anchored:
            add_proximal_gradient(anchored, self._proximal_mu)
        optimizer.step()

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
    @property
    def federated_keys(self) -> tuple[str, ...]:
        """Keys of :meth:`federated_state`, in a stable order."""
        return tuple(self.networks.state_dict())

    def federated_state(self) -> dict[str, Tensor]:
        """Detached contiguous CPU copies of all network parameters (online and target).

        Keys look like ``actor.layers.0.weight`` or ``critic_target.layers.4.bias``; see
        :func:`is_target_key`. Optimizer moments, the replay buffer and the noise stay
        private to the agent.
        """
        return {
            key: tensor.detach().to("cpu", memory_format=torch.contiguous_format, copy=True)
            for key, tensor in self.networks.state_dict().items()
        }

    def load_federated_state(self, state: dict[str, Tensor]) -> None:
        """Copy a :meth:`federated_state`-shaped dict into the networks. Strict: a missing or
        unexpected key, or a shape mismatch, raises ``ValueError`` naming the key, and
        nothing is modified."""
        self.networks.load_strict(state)

    def set_proximal_anchor(self, mu: float) -> None:
        """FedProx (Li et al. 2020): from now on each update adds mu/2 ||w - w_anchor||^2 to
        the critic and actor losses, w_anchor the online networks as they are now (the
        global model just loaded). ``mu`` = 0 removes the term."""
        if not mu >= 0:
            raise ValueError(f"proximal mu must be >= 0, got {mu!r}")

        def anchored(net: nn.Module) -> list[tuple[Tensor, Tensor]]:
            return [(p, p.detach().clone()) for p in net.parameters()] if mu else []

        self._proximal_mu = float(mu)
        self._proximal_actor, self._proximal_critic = anchored(self.actor), anchored(self.critic)

    def sync_targets(self) -> None:
        """Hard-copy the online networks into the targets (e.g. after FedAvg of onlines)."""
        hard_update(self.networks.target_parameters(), self.networks.online_parameters())

    # -------------------------------------------------------------- checkpoints
    def save(self, path: str | os.PathLike[str], include_buffer: bool = False) -> None:
        """Write networks, optimizers, noise, counters and generators (and the buffer),
        atomically; the file loads with ``torch.load(weights_only=True)``."""
        checkpoint.write_checkpoint(checkpoint.agent_payload(self, include_buffer), path)

    def restore(self, path: str | os.PathLike[str]) -> None:
        """Restore a :meth:`save` file into this agent (same config and spaces): exact
        resume; without a saved buffer the agent resumes with an empty one.

        Raises:
            CheckpointError: unreadable or foreign file, or one saved by an agent with a
                different config, spaces or network shapes (checked before anything is
                modified).
        """
        checkpoint.restore_agent(self, path)

    @classmethod
    def from_checkpoint(
        cls, path: str | os.PathLike[str], observation_space: Space | None = None,
        action_space: spaces.Box | None = None, device: str | torch.device = "cpu",
    ) -> DDPG:  # fmt: skip
        """A new agent built with the checkpoint's config and seed, then :meth:`restore`-d.
        Spaces left out are rebuilt from the file (the observation bounds as unbounded)."""
        data = checkpoint.read_checkpoint(path)
        config = checkpoint.saved_config(data, path)
        try:
            seed = int(data["seed"])
        except (KeyError, TypeError, ValueError) as error:
            raise checkpoint.CheckpointError(f"{path}: malformed checkpoint ({error!r})") from error
        if observation_space is None or action_space is None:
            saved_observation, saved_action = checkpoint.spaces_of(data, path)
            observation_space = observation_space or saved_observation
            action_space = action_space or saved_action
        agent = cls(observation_space, action_space, config, seed=seed, device=device)
        agent.restore(path)
        return agent

    @checkpoint.class_only
    def load(cls, path: str | os.PathLike[str], device: str | torch.device = "cpu") -> DDPG:
        """A new agent from a :meth:`save` file, a run's ``models/*.pt`` included: its
        config, seed and spaces come from the file (``DDPG.load(path)``, as in
        Stable-Baselines3). Checkpoints load with ``weights_only=True``.

        Raises:
            CheckpointError: unreadable, foreign or malformed file.
        """
        return cls.from_checkpoint(path, device=device)
