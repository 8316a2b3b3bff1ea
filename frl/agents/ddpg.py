"""DDPG (Lillicrap et al. 2016) for gymnasium Box spaces, with a federated-state interface.

The agent wires together parts that each do one thing: the four networks
(:class:`~frl.agents.networks.ActorCritic`), the explorer (warm-up and noise), the
transition writer (n-step transitions, a teacher's labels) into the replay buffer, acting
(:mod:`frl.agents.acting`), a collision budget (:mod:`frl.agents.constraint`), the losses'
maths (:mod:`~frl.agents.functional`, :mod:`~frl.agents.guide`), the federated state
(:mod:`~frl.agents.federated`) and checkpoints (:mod:`~frl.agents.checkpoint`). What is
left here is the algorithm: observe, and the update, :meth:`DDPG._train_step`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import torch
from gymnasium import spaces
from torch import Tensor

from frl.agents.acting import Acting, ActionScale
from frl.agents.checkpoint import Checkpointing
from frl.agents.config import DDPGConfig
from frl.agents.constraint import CollisionConstraint
from frl.agents.critic_readings import critic_values
from frl.agents.explorer import Explorer
from frl.agents.federated import FederatedAgent
from frl.agents.functional import (
    ProximalPull,
    critic_loss,
    inverting_gradients_loss,
    lower_tail_mean,
    soft_update,
)
from frl.agents.guide import imitation_loss
from frl.agents.learn import LearnCallback, learn, read_losses
from frl.agents.networks import build_actor_critic, make_adam
from frl.agents.observations import ObservationLayout
from frl.agents.precision import autocast, resolve_precision
from frl.agents.replay_buffer import Batch, ReplayBuffer
from frl.agents.sparse_linear import SparseRows
from frl.agents.transitions import Teacher, TransitionWriter
from frl.agents.update_graph import GraphedUpdate, keeps_one_layout

Path = str | os.PathLike[str]


class CriticLosses(NamedTuple):
    """The reward critic's phase of an update: its loss and statistics, and what the
    later phases read of it (the target actor's next actions, the critics' last hidden
    layers, detached)."""

    loss: Tensor
    stats: dict[str, Tensor]
    next_actions: Tensor
    hidden: Tensor
    next_hidden: Tensor


class DDPG(Acting, FederatedAgent, Checkpointing):
    """Deep Deterministic Policy Gradient agent for a Box observation and a Box action space.

    Args:
        observation_space: any Box, or a Dict of Boxes (:mod:`frl.agents.observations`),
            flattened. Large ones (``DDPGConfig.sparse``) take the sparse path.
        action_space: a Box with finite bounds; the actor works in [-1, 1], noise included.
        config: hyperparameters; ``None`` means the paper's Table II defaults.
        seed: seeds every random stream: network init, noise, replay sampling and warm-up
            actions each get a child of ``np.random.SeedSequence(seed)``.
        init_seed: seeds the network initialisation alone instead (FedAvg's clients start
            from one initial global model). None: the init stream of ``seed``.
        device: where networks and training batches live; nothing requires a GPU.

    As in Stable-Baselines3: :meth:`learn`, ``act`` and ``predict``
    (:class:`~frl.agents.acting.Acting`), ``save`` and ``DDPG.load``
    (:class:`~frl.agents.checkpoint.Checkpointing`); FedAvg's flat state_dicts:
    :class:`~frl.agents.federated.FederatedAgent`.
    Loops of their own call :meth:`episode_start` at each reset and
    :func:`frl.agents.training_step` (act, observe, update) at each step.
    """

    def __init__(
        self, observation_space: spaces.Box | spaces.Dict, action_space: spaces.Box,
        config: DDPGConfig | None = None, seed: int = 0, device: str | torch.device = "cpu",
        init_seed: int | None = None,
    ) -> None:  # fmt: skip
        self.layout = ObservationLayout(observation_space)
        """How observations become the flat vectors the networks and the buffer hold."""
        self.scale = ActionScale(action_space)
        self.config = cfg = config if config is not None else DDPGConfig()
        self.seed, self.device = int(seed), torch.device(device)
        self.obs_shape, self.obs_dim = self.layout.shape, self.layout.num_features
        self.action_shape, self.action_dim = self.scale.shape, self.scale.low.size
        self.action_low, self.action_high = self.scale.low, self.scale.high
        self.sparse = cfg.use_sparse(self.obs_dim, self.device.type)
        """Networks see :class:`SparseRows` batches (same function, fewer multiply-adds)."""
        self.precision = resolve_precision(cfg.precision, self.device)
        """What updates compute in: ``float32`` or ``bf16`` (acting is always float32)."""

        init_seq, noise_seq, buffer_seq, warmup_seq, wheel_seq = np.random.SeedSequence(
            self.seed
        ).spawn(5)  # the first four children are those spawn(4) gave before the fifth
        if init_seed is not None:
            init_seq = np.random.SeedSequence(int(init_seed))
        init = torch.Generator().manual_seed(int(init_seq.generate_state(1, np.uint64)[0]))

        self.networks = nets = build_actor_critic(
            cfg, self.obs_dim, self.action_dim, self.layout, init, self.device
        )
        self.actor, self.critic = nets.actor, nets.critic
        self.actor_target, self.critic_target = nets.actor_target, nets.critic_target
        self.actor_optimizer = make_adam(list(nets.actor.parameters()), cfg.actor_lr, self.device)
        self.critic_optimizer = make_adam(
            list(nets.critic.parameters()), cfg.critic_lr, self.device
        )
        self.constraint = (
            CollisionConstraint(cfg, nets, self.device, self._autocast) if cfg.costed else None
        )
        """The collision budget (:mod:`frl.agents.constraint`); None without one."""
        rng = np.random.default_rng
        self.explorer = Explorer(
            cfg, self.action_dim, rng(noise_seq), rng(warmup_seq), rng(wheel_seq)
        )
        # Compact storage whenever the observation is large, even for a dense network.
        compact = cfg.sparse.input is True or self.obs_dim >= cfg.sparse.min_features
        encoder = nets.critic.encoder
        self.buffer = ReplayBuffer(
            cfg.buffer_size, self.obs_shape, self.action_dim, rng(buffer_seq), sparse=compact,
            sparse_width=cfg.sparse.capacity, guided=cfg.guided, costed=cfg.costed,
            vehicle_geometry=None if encoder is None else encoder.geometry,
            costs_to_go=cfg.costs_to_go,
        )  # fmt: skip
        self.teacher = Teacher(cfg.guide, self.layout, self.scale) if cfg.guided else None
        self.writer = TransitionWriter(
            self.buffer, cfg.n_step, cfg.gamma, self.teacher, hold_episode=cfg.costs_to_go
        )
        self.proximal = ProximalPull()
        """FedProx's pull towards the global model (off until :meth:`set_proximal_anchor`)."""
        self.update_graph = (
            GraphedUpdate(self._train_step, self.device, self._tensors_read)
            if cfg.cuda_graph and self.device.type == "cuda" and keeps_one_layout(cfg, self.sparse)
            else None
        )
        """The update replayed as a CUDA graph (:mod:`frl.agents.update_graph`); None
        where updates run eagerly (a CPU, ``cuda_graph=False``)."""
        self.stacked_in: Any = None
        """The stacked update this agent learns in with others (:mod:`frl.agents.stacked`),
        which holds its parameters and optimizer state; None: it learns on its own."""
        self.last_policy_action = np.full(self.action_dim, np.nan)
        """The policy's normalised action (before noise) behind the last :meth:`act`; NaN
        during the uniform warm-up."""
        self.num_env_steps, self.num_updates = 0, 0
        """Transitions passed to :meth:`observe`, and gradient steps taken."""
        self.episode_returns: list[float] = []
        """Returns of the episodes :meth:`learn` finished, in order (and their lengths)."""
        self.episode_lengths: list[int] = []
        self.learn_calls = 0
        """Calls of :meth:`learn` so far (the first seeds the environment's reset)."""

    # ------------------------------------------------------------------ acting
    def _autocast(self) -> Any:
        """The update's forward passes (not its optimizer steps): bf16 autocast or none."""
        return autocast(self.device, self.precision)

    def learn(
        self, env: Any, total_timesteps: int, callback: LearnCallback | None = None,
        progress_bar: bool = False, tensorboard_log: Path | None = None, seed: int | None = None,
    ) -> DDPG:  # fmt: skip
        """Train on one gymnasium environment (Stable-Baselines3's ``model.learn``); see
        :func:`frl.agents.learn.learn`."""
        return learn(self, env, total_timesteps, callback, progress_bar, tensorboard_log, seed)

    def set_guide(self, policy: Callable[[Any], Any] | None) -> None:
        """A guided agent's teacher (``DDPGConfig.guide``): observation -> env action. frl's
        vehicles install it; :func:`frl.policies.install_guide` does for a loaded agent."""
        if self.teacher is not None:
            self.teacher.driver = policy

    @property
    def needs_guide(self) -> bool:
        """Whether the agent stores a teacher's actions and has no teacher installed yet."""
        return self.teacher is not None and self.teacher.driver is None

    def episode_start(self) -> None:
        """Call after every ``env.reset()``: the previous episode's pending n-step steps,
        cut off by a time limit, bootstrap from its last state, and count for the collision
        budget; the noise restarts."""
        self.writer.end_episode()
        self._end_training_episode()
        self.explorer.episode_start()

    def observe(
        self, obs: Any, action: Any, reward: float, next_obs: Any, terminated: bool,
        cost: float = 0.0,
    ) -> None:  # fmt: skip
        """Store a transition. Pass gymnasium's ``terminated``, not ``terminated or truncated``:
        a time-limit cut-off is not a terminal state and must still bootstrap. ``cost``: the
        step's collisions (``info["cost"]`` of frl's environment), which a collision budget
        counts and its cost critic learns; other agents ignore it."""
        flat, next_flat = self.layout.flat(obs), self.layout.flat(next_obs)
        unit = self.scale.to_unit(action)
        cost = float(cost) if self.constraint is not None else 0.0
        self.writer.write(flat, unit, float(reward), next_flat, bool(terminated), cost)
        self.num_env_steps += 1
        if self.constraint is not None and not self.explorer.teacher_driving:
            # The budget follows the agent's own driving, not its teacher's.
            self.constraint.observe_cost(cost)
        if terminated:
            self._end_training_episode()

    def _end_training_episode(self) -> None:
        """The running episode ended: a collision budget counts it."""
        if self.constraint is not None:
            self.constraint.episode_ends()

    # ---------------------------------------------------------------- learning
    def update(self) -> dict[str, float]:
        """One update if due (``learning_starts`` transitions observed, a batch in the
        buffer, ``num_env_steps`` a multiple of ``train_freq``): its losses, or ``{}``."""
        return read_losses([self.update_unread()])[0]

    def update_unread(self) -> dict[str, Tensor | float]:
        """:meth:`update`, its losses left as tensors: reading one waits for the device, so
        a training loop reads a window's at once (:func:`frl.agents.learn.read_losses`)."""
        cfg = self.config
        if not self.update_due():
            return {}
        if self.stacked_in is not None:
            raise RuntimeError(
                "this agent learns in a stacked update with others (frl.agents.stacked): "
                "update them together there, or release them first"
            )
        slots = self.buffer.sample_slots(cfg.batch_size)
        transposed = cfg.encoder == "flat"
        if self.update_graph is not None:  # it copies the host batch to its static one
            batch = self.buffer.gather(slots, self.sparse, "cpu", transposed)
            losses: dict[str, Tensor | float] = dict(self.update_graph(batch))
        else:
            batch = self.buffer.gather(slots, self.sparse, self.device, transposed)
            losses = dict(self._train_step(batch))
        self.num_updates += 1
        if self.constraint is not None:
            losses.update(self.constraint.stats())
        return losses

    def update_due(self) -> bool:
        """Whether :meth:`update` would take a step now: ``learning_starts`` transitions
        observed, a batch in the buffer, ``num_env_steps`` a multiple of ``train_freq``."""
        cfg = self.config
        return (
            self.num_env_steps >= cfg.learning_starts
            and len(self.buffer) >= cfg.batch_size
            and self.num_env_steps % cfg.train_freq == 0
        )

    def _train_step(self, batch: Batch) -> dict[str, Tensor]:
        """One DDPG update (Lillicrap et al. 2016, Algorithm 1) on a sampled batch.

        Its losses are computed by the forward-only phases below (:meth:`critic_losses`,
        the constraint's :meth:`~frl.agents.constraint.CollisionConstraint.losses`,
        :meth:`actor_losses`), which :mod:`frl.agents.stacked` runs for many vehicles at
        once; the optimizer steps are taken here."""
        cfg, nets = self.config, self.networks
        critic = self.critic_losses(batch)
        self._descend(self.critic_optimizer, critic.loss)
        stats = dict(critic.stats)
        if self.constraint is not None:
            cost_loss, cost_stats = self.constraint.losses(
                batch, critic.next_actions, self.discount(batch), critic.hidden,
                critic.next_hidden,
            )  # fmt: skip
            self._descend(self.constraint.optimizer, cost_loss)
            stats.update(cost_stats)
        stats.update(self._actor_step(batch))
        # Targets: follow the online networks by Polyak averaging.
        soft_update(nets.target_parameters(), nets.online_parameters(), cfg.tau)
        return stats

    def discount(self, batch: Batch) -> float | Tensor:
        """gamma, or for n-step transitions gamma to the steps each one spans."""
        cfg = self.config
        return cfg.gamma**batch.horizons if cfg.n_step > 1 else cfg.gamma

    def critic_losses(self, batch: Batch) -> CriticLosses:
        """The reward critic's loss on ``batch`` (forward only): down it to the n-step TD
        target of the target networks. Q-values are float32 (precision.float32_layer), and
        so are the targets and the losses."""
        nets = self.networks
        with self._autocast(), torch.no_grad():
            next_actions = nets.actor_target(batch.next_obs)
            next_q, next_hidden = nets.critic_target.values_and_hidden(batch.next_obs, next_actions)
        with self._autocast():
            q, hidden = nets.critic.values_and_hidden(batch.obs, batch.actions)
        loss, td_error = critic_loss(
            q, batch.rewards, batch.terminated, next_q, self.discount(batch),
            self.config.critic.kind == "quantile",
        )  # fmt: skip
        stats = {"critic_loss": loss.detach(), "q_mean": q.detach().mean(), "td_error": td_error}
        return CriticLosses(loss, stats, next_actions, hidden.detach(), next_hidden)

    def _actor_step(self, batch: Batch) -> dict[str, Tensor]:
        """Up the objective's gradient at the actor's own action (plus a teacher's pull).
        The critics are frozen, so backward computes dQ/da and no critic weight gradient."""
        nets = self.networks
        frozen = [net for net in (nets.critic, nets.cost_critic) if net is not None]
        for net in frozen:
            net.requires_grad_(False)
        try:
            with self._autocast():
                preactivation = nets.actor.preactivation(batch.obs)
            if self.config.actor_update == "tanh":
                q_policy = self.objective(batch.obs, torch.tanh(preactivation))
                dq_da = None
            else:
                action = self.bounded_action(preactivation)
                q_policy = self.objective(batch.obs, action)
                (dq_da,) = torch.autograd.grad(q_policy.sum(), action)
            actor_loss, stats = self.actor_losses(batch, preactivation, q_policy, dq_da)
            self._descend(self.actor_optimizer, actor_loss)
        finally:
            for net in frozen:
                net.requires_grad_(True)
        return stats

    @staticmethod
    def bounded_action(preactivation: Tensor) -> Tensor:
        """Inverting gradients' action: the actor's output clipped to [-1, 1], a leaf
        whose gradient dQ/da the actor's loss reads."""
        return preactivation.detach().clamp(-1.0, 1.0).requires_grad_(True)

    def actor_losses(
        self, batch: Batch, preactivation: Tensor, q_policy: Tensor, dq_da: Tensor | None
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """The actor's loss from its unbounded action ``preactivation`` and the objective
        ``q_policy`` at the action taken: ``tanh`` (``dq_da`` None), -objective(s,
        tanh(p)); else inverting gradients with dQ/da at the clipped action; plus a
        teacher's pull."""
        cfg = self.config
        if dq_da is None:
            actor_loss = -q_policy.mean()
        else:
            actor_loss = inverting_gradients_loss(preactivation, dq_da)
        stats = {"actor_loss": -q_policy.detach().mean()}
        if cfg.guide_weight > 0 and batch.guide_actions is not None:  # a teacher's pull
            imitation = cfg.guide_weight * imitation_loss(preactivation, batch.guide_actions)
            actor_loss = actor_loss + imitation
            stats["imitation_loss"] = imitation.detach()
        return actor_loss, stats

    def objective(
        self, obs: Tensor | SparseRows, action: Tensor, price: tuple[Tensor, Tensor] | None = None
    ) -> Tensor:
        """What the actor climbs at ``action``, per sample: Q_r (the CVaR of the return's
        quantiles below ``cvar_alpha`` = 1), priced by a collision budget's constraint
        (``price``: its multiplier and 1 + multiplier; None: the constraint's own)."""
        cfg, nets, constraint = self.config, self.networks, self.constraint
        with self._autocast():
            if constraint is not None and constraint.reads_critic_hidden:
                value, hidden = nets.critic.values_and_hidden(obs, action)
            else:
                value, hidden = nets.critic(obs, action), None
        if cfg.critic.kind == "quantile":
            value = lower_tail_mean(value, cfg.critic.cvar_alpha)
        if constraint is not None:
            value = constraint.price(value, obs, action, hidden, price)
        return value

    def _tensors_read(self) -> list[Tensor]:
        """What an update reads besides its batch and keeps from one update to the next:
        the networks, the optimizers' state, FedProx's anchors. A captured update
        replays on these very tensors, so a new one among them means a new capture."""
        optimizers = [self.actor_optimizer, self.critic_optimizer]
        if self.constraint is not None:
            optimizers.append(self.constraint.optimizer)
        tensors = [*self.networks.parameters(), *self.networks.buffers()]
        for optimizer in optimizers:
            for state in optimizer.state.values():
                tensors += [value for value in state.values() if isinstance(value, Tensor)]
        tensors += [anchor for pairs in self.proximal.anchors.values() for _, anchor in pairs]
        return tensors

    def _descend(self, optimizer: torch.optim.Optimizer, loss: Tensor) -> None:
        """One optimizer step down ``loss``, plus FedProx's pull where it is anchored. The
        gradients are let go after the step: the next backward makes new ones anyway, and a
        process hosting many vehicles would otherwise keep every vehicle's."""
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.proximal.add_gradient(optimizer)
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)

    def critic_values(self, observations: Any, actions: Any, cost: bool = False) -> np.ndarray:
        """Q(s, a) of the online critic, or with ``cost`` the cost critic's; see
        :func:`frl.agents.critic_readings.critic_values`."""
        return critic_values(self, observations, actions, cost)
