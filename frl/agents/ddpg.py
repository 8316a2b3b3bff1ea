"""DDPG (Lillicrap et al. 2016) for gymnasium Box spaces, with a federated-state interface.

The agent wires together parts that each do one thing: the four networks
(:class:`~frl.agents.networks.ActorCritic`), the explorer (warm-up and noise), the
transition writer (n-step transitions, a teacher's labels) into the replay buffer, acting
on one observation (:mod:`frl.agents.acting`), the losses' maths (:mod:`~frl.agents.functional`,
:mod:`~frl.agents.guide`) and checkpoints (:mod:`~frl.agents.checkpoint`). What is left
here is the algorithm: act, observe, and the update, :meth:`DDPG._train_step`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from gymnasium import spaces
from torch import Tensor

from frl.agents import checkpoint
from frl.agents.acting import ActionScale, actor_action
from frl.agents.budget_episodes import BudgetEpisodes
from frl.agents.config import DDPGConfig
from frl.agents.explorer import Explorer
from frl.agents.functional import (
    ProximalPull,
    hard_update,
    inverting_gradients_loss,
    lower_tail_mean,
    quantile_huber_loss,
    soft_update,
    td_target,
)
from frl.agents.guide import imitation_loss
from frl.agents.lagrange import PIDLagrangian
from frl.agents.learn import LearnCallback, learn
from frl.agents.networks import (
    TARGET_NAMES,
    Actor,
    ActorCritic,
    CostHead,
    Critic,
    build_cost_head,
    build_network,
    make_adam,
)
from frl.agents.observations import ObservationLayout
from frl.agents.precision import autocast, resolve_precision
from frl.agents.replay_buffer import Batch, ReplayBuffer
from frl.agents.sparse_linear import SparseRows
from frl.agents.transitions import Teacher, TransitionWriter

Path = str | os.PathLike[str]


def is_target_key(name: str) -> bool:
    """Whether a federated-state key belongs to a target network."""
    return name.startswith(tuple(f"{target}." for target in TARGET_NAMES))


class DDPG:
    """Deep Deterministic Policy Gradient agent for a Box observation and a Box action space.

    Args:
        observation_space: any Box, or a Dict of Boxes (:mod:`frl.agents.observations`),
            flattened. Large ones (``DDPGConfig.sparse_input``) take the sparse path.
        action_space: a Box with finite bounds; the actor works in [-1, 1], noise included.
        config: hyperparameters; ``None`` means the paper's Table II defaults.
        seed: seeds every random stream: network init, noise, replay sampling and warm-up
            actions each get a child of ``np.random.SeedSequence(seed)``.
        init_seed: seeds the network initialisation alone instead (FedAvg's clients start
            from one initial global model). None: the init stream of ``seed``.
        device: where networks and training batches live; nothing requires a GPU.

    As in Stable-Baselines3: :meth:`learn`, :meth:`predict`, :meth:`save`, ``DDPG.load``.
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
        self.sparse = cfg.use_sparse(self.obs_dim)
        """Networks see :class:`SparseRows` batches (same function, fewer multiply-adds)."""
        self.precision = resolve_precision(cfg.precision, self.device)
        """What updates compute in: ``float32`` or ``bf16`` (acting is always float32)."""

        init_seq, noise_seq, buffer_seq, warmup_seq = np.random.SeedSequence(self.seed).spawn(4)
        if init_seed is not None:
            init_seq = np.random.SeedSequence(int(init_seed))
        init = torch.Generator().manual_seed(int(init_seq.generate_state(1, np.uint64)[0]))

        def network(kind: type[Actor] | type[Critic], outputs: int = 1) -> Any:
            return build_network(
                kind, self.obs_dim, self.action_dim, cfg, self.layout, init, self.device, outputs
            )

        actor = network(Actor)
        critic = network(Critic, cfg.quantiles if cfg.critic == "quantile" else 1)
        # Built last, so that the actor's and critic's initial weights do not depend on it.
        cost_critic = None
        if cfg.costed:
            separate = cfg.cost_critic == "separate"
            cost_critic = network(Critic) if separate else build_cost_head(cfg, init, self.device)
        self.networks = nets = ActorCritic(actor, critic, cost_critic)
        self.actor, self.critic = nets.actor, nets.critic
        self.actor_target, self.critic_target = nets.actor_target, nets.critic_target
        self.actor_optimizer = make_adam(list(actor.parameters()), cfg.actor_lr, self.device)
        self.critic_optimizer = make_adam(list(critic.parameters()), cfg.critic_lr, self.device)
        self.cost_critic_optimizer = (
            None
            if cost_critic is None
            else make_adam(list(cost_critic.parameters()), cfg.critic_lr, self.device)
        )
        """The cost critic's Adam, at the reward critic's rate; None without a budget."""
        self.lagrangian = (
            PIDLagrangian(cfg.collision_budget, cfg.lagrange_gains, cfg.lagrange_window)
            if cfg.collision_budget is not None  # cfg.costed, spelled for the type checker
            else None
        )
        """The collision budget's multiplier (:mod:`frl.agents.lagrange`); None without."""
        self.budget_episodes = (
            BudgetEpisodes(cfg.budget_noise_free_every) if self.lagrangian is not None else None
        )
        """Which training episodes the budget counts, and the running one's collisions."""
        rng = np.random.default_rng
        self.explorer = Explorer(cfg, self.action_dim, rng(noise_seq), rng(warmup_seq))
        # Compact storage whenever the observation is large, even for a dense network.
        compact = cfg.sparse_input is True or self.obs_dim >= cfg.sparse_min_features
        self.buffer = ReplayBuffer(
            cfg.buffer_size, self.obs_shape, self.action_dim, rng(buffer_seq), sparse=compact,
            sparse_width=cfg.sparse_capacity, guided=cfg.guided, costed=cfg.costed,
        )  # fmt: skip
        self.teacher = Teacher(cfg.guide, self.layout, self.scale) if cfg.guided else None
        self.writer = TransitionWriter(self.buffer, cfg.n_step, cfg.gamma, self.teacher)
        self.proximal = ProximalPull()
        """FedProx's pull towards the global model (off until :meth:`set_proximal_anchor`)."""
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

    def _policy_action(self, flat: Any) -> np.ndarray:
        """The deterministic policy's normalised action on one flat observation."""
        flat = np.asarray(flat, dtype=np.float32).reshape(-1)
        if flat.size != self.obs_dim:
            raise ValueError(f"expected an observation of shape {self.obs_shape}")
        return actor_action(self.actor, flat, self.sparse)

    def act(self, obs: Any, explore: bool = True) -> np.ndarray:
        """Action for one observation, float32 within the bounds: with ``explore`` the
        explorer's (held uniform warm-up actions, then the policy's plus noise), without
        it the deterministic policy's."""
        if explore and self.explorer.in_warmup(self.num_env_steps):
            self.last_policy_action = np.full(self.action_dim, np.nan)
            return self.scale.from_unit(self.explorer.warmup_action())
        action = self.last_policy_action = self._policy_action(self.layout.flat(obs))
        noisy = explore and not (self.budget_episodes and self.budget_episodes.noise_free)
        return self.scale.from_unit(self.explorer.noisy(action) if noisy else action)

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:  # fmt: skip
        """``(action, None)`` for one observation or a batch (Stable-Baselines3's
        signature; no recurrent state). ``deterministic=False`` adds what the exploration
        noise would add next, drawn from a copy: ``predict`` never changes the agent. A
        ``ValueError`` names an observation of neither the space's shape nor a batch's."""
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
        env_actions = np.stack([self.scale.from_unit(action) for action in actions])
        return (env_actions if batched else env_actions[0]), None

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
        budget; the noise restarts (the budget may have this episode driven without it)."""
        self.writer.end_episode()
        self._end_training_episode()
        self.explorer.episode_start()
        if self.budget_episodes is not None:
            self.budget_episodes.begin(self.explorer.in_warmup(self.num_env_steps))

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
        cost = float(cost) if self.budget_episodes is not None else 0.0
        self.writer.write(flat, unit, float(reward), next_flat, bool(terminated), cost)
        self.num_env_steps += 1
        if self.budget_episodes is not None:
            self.budget_episodes.step(cost)
        if terminated:
            self._end_training_episode()

    def _end_training_episode(self) -> None:
        """The running episode ended: the multiplier follows its collisions, if counted."""
        if self.budget_episodes is not None and self.lagrangian is not None:
            collisions = self.budget_episodes.finish()
            if collisions is not None:
                self.lagrangian.episode_end(collisions)

    # ---------------------------------------------------------------- learning
    def update(self) -> dict[str, float]:
        """One update if due (``learning_starts`` transitions observed, a batch in the
        buffer, ``num_env_steps`` a multiple of ``train_freq``): its losses, or ``{}``."""
        cfg = self.config
        if (
            self.num_env_steps < cfg.learning_starts
            or len(self.buffer) < cfg.batch_size
            or self.num_env_steps % cfg.train_freq != 0
        ):
            return {}
        slots = self.buffer.sample_slots(cfg.batch_size)
        stats = self._train_step(self.buffer.gather(slots, self.sparse, self.device))
        self.num_updates += 1
        losses = {name: value.item() for name, value in stats.items()}
        if self.lagrangian is not None:
            losses["lagrange_multiplier"] = self.lagrangian.multiplier
            if self.lagrangian.recent:  # no rate before the first counted episode
                losses["collision_rate"] = self.lagrangian.collision_rate
        return losses

    def _train_step(self, batch: Batch) -> dict[str, Tensor]:
        """One DDPG update (Lillicrap et al. 2016, Algorithm 1) on a sampled batch."""
        cfg, nets = self.config, self.networks
        # Critic: squared error to the n-step TD target of the target networks (for a
        # quantile critic, the quantile Huber loss to the target's quantiles). Q-values are
        # float32 (precision.float32_layer), and so are the targets and the losses.
        with self._autocast(), torch.no_grad():
            next_actions = nets.actor_target(batch.next_obs)
            next_q, next_hidden = nets.critic_target.values_and_hidden(batch.next_obs, next_actions)
        with self._autocast():
            q, hidden = nets.critic.values_and_hidden(batch.obs, batch.actions)
        discount = cfg.gamma**batch.horizons if cfg.n_step > 1 else cfg.gamma
        if cfg.critic == "quantile":
            per_sample = discount.unsqueeze(-1) if isinstance(discount, Tensor) else discount
            target_q = td_target(
                batch.rewards.unsqueeze(-1), batch.terminated.unsqueeze(-1), next_q, per_sample
            )
            critic_loss = quantile_huber_loss(q, target_q)
        else:
            target_q = td_target(batch.rewards, batch.terminated, next_q, discount)
            critic_loss = F.mse_loss(q, target_q)
        self._descend(self.critic_optimizer, critic_loss)
        q = q.detach()
        stats = {"critic_loss": critic_loss.detach(), "q_mean": q.mean()}
        if cfg.critic == "quantile":
            stats["td_error"] = (q.mean(-1) - target_q.mean(-1)).abs().mean()
        else:
            stats["td_error"] = (q - target_q).abs().mean()
        if nets.cost_critic is not None:
            critic_hidden = (hidden.detach(), next_hidden)
            stats.update(self._cost_critic_step(batch, next_actions, discount, critic_hidden))
        # Actor: up the critic's gradient at its own action. The critics are frozen, so
        # backward computes dQ/da and no critic weight gradient.
        frozen = [net for net in (nets.critic, nets.cost_critic) if net is not None]
        for net in frozen:
            net.requires_grad_(False)
        try:
            with self._autocast():
                preactivation = nets.actor.preactivation(batch.obs)
            actor_loss, q_policy = self._actor_loss(batch, preactivation)
            stats["actor_loss"] = -q_policy.detach().mean()
            if cfg.guide_weight > 0 and batch.guide_actions is not None:  # a teacher's pull
                imitation = cfg.guide_weight * imitation_loss(preactivation, batch.guide_actions)
                actor_loss = actor_loss + imitation
                stats["imitation_loss"] = imitation.detach()
            self._descend(self.actor_optimizer, actor_loss)
        finally:
            for net in frozen:
                net.requires_grad_(True)
        # Targets: follow the online networks by Polyak averaging.
        soft_update(nets.target_parameters(), nets.online_parameters(), cfg.tau)
        return stats

    def _cost_critic_step(
        self, batch: Batch, next_actions: Tensor, discount: float | Tensor,
        critic_hidden: tuple[Tensor, Tensor],
    ) -> dict[str, Tensor]:  # fmt: skip
        """The cost critic's update: squared error to the n-step TD target of the
        discounted collisions to come, bootstrapped from its own target network. A
        :class:`CostHead` reads ``critic_hidden``, the last hidden layers of the critic at
        the batch and of the target critic at the next states, detached."""
        nets = self.networks
        assert nets.cost_critic is not None and nets.cost_critic_target is not None
        assert batch.costs is not None
        hidden, next_hidden = critic_hidden
        with self._autocast(), torch.no_grad():
            next_cost = self._cost(
                nets.cost_critic_target, batch.next_obs, next_actions, next_hidden
            )
        with self._autocast():
            cost_q = self._cost(nets.cost_critic, batch.obs, batch.actions, hidden)
        target = td_target(batch.costs, batch.terminated, next_cost, discount)
        loss = F.mse_loss(cost_q, target)
        assert self.cost_critic_optimizer is not None
        self._descend(self.cost_critic_optimizer, loss)
        return {"cost_critic_loss": loss.detach(), "cost_q_mean": cost_q.detach().mean()}

    def _objective(self, obs: Tensor | SparseRows, action: Tensor) -> Tensor:
        """What the actor climbs at ``action``, per sample: Q_r (the CVaR of the return's
        quantiles below ``cvar_alpha`` = 1), less lambda Q_c under a collision budget,
        divided by 1 + lambda so that its scale stays that of a return as lambda grows
        (Stooke et al. 2020; OmniSafe's DDPG-Lag)."""
        cfg, nets = self.config, self.networks
        with self._autocast():
            if isinstance(nets.cost_critic, CostHead):
                value, hidden = nets.critic.values_and_hidden(obs, action)
            else:
                value, hidden = nets.critic(obs, action), None
        if cfg.critic == "quantile":
            value = lower_tail_mean(value, cfg.cvar_alpha)
        if nets.cost_critic is not None and self.lagrangian is not None:
            price = self.lagrangian.multiplier
            with self._autocast():
                cost = self._cost(nets.cost_critic, obs, action, hidden)
            value = (value - price * cost) / (1.0 + price)
        return value

    @staticmethod
    def _cost(
        network: Critic | CostHead, obs: Tensor | SparseRows, action: Tensor,
        hidden: Tensor | None,
    ) -> Tensor:  # fmt: skip
        """Q_c at ``(obs, action)``: a separate cost critic reads them, a cost head the
        critic's last hidden layer there (``hidden``)."""
        if isinstance(network, CostHead):
            assert hidden is not None
            return network(hidden)
        return network(obs, action)

    def _actor_loss(self, batch: Batch, preactivation: Tensor) -> tuple[Tensor, Tensor]:
        """From the actor's unbounded action ``p``: the loss, and the objective at the
        action taken. ``tanh``: -objective(s, tanh(p)); else inverting gradients."""
        if self.config.actor_update == "tanh":
            q_policy = self._objective(batch.obs, torch.tanh(preactivation))
            return -q_policy.mean(), q_policy
        action = preactivation.detach().clamp(-1.0, 1.0).requires_grad_(True)
        q_policy = self._objective(batch.obs, action)
        (dq_da,) = torch.autograd.grad(q_policy.sum(), action)
        return inverting_gradients_loss(preactivation, dq_da), q_policy

    def _descend(self, optimizer: torch.optim.Optimizer, loss: Tensor) -> None:
        """One optimizer step down ``loss``, plus FedProx's pull where it is anchored."""
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.proximal.add_gradient(optimizer)
        optimizer.step()

    def critic_values(self, observations: Any, actions: Any, cost: bool = False) -> np.ndarray:
        """Q(s, a) of the online critic for a batch of observations (an array, or for a
        Dict space a sequence of them) and env-unit actions: the mean return (a quantile
        critic's quantiles averaged), or with ``cost`` the cost critic's discounted
        collisions to come."""
        if cost and self.networks.cost_critic is None:
            raise ValueError("this agent has no cost critic (DDPGConfig.collision_budget)")
        if self.layout.parts is not None and not isinstance(observations, np.ndarray):
            observations = [self.layout.flat(o) for o in observations]
        x = torch.from_numpy(np.asarray(observations, dtype=np.float32).reshape(-1, self.obs_dim))
        unit = self.scale.to_unit(np.asarray(actions).reshape(len(x), -1), batch=True)
        inputs = SparseRows.from_dense(x).to(self.device) if self.sparse else x.to(self.device)
        action = torch.from_numpy(unit.astype(np.float32)).to(self.device)
        cost_critic = self.networks.cost_critic
        with torch.no_grad(), self._autocast():
            if not cost:
                q = self.critic(inputs, action)
            else:  # the reward critic's pass only where a cost head reads it
                assert cost_critic is not None
                head = isinstance(cost_critic, CostHead)
                hidden = self.critic.values_and_hidden(inputs, action)[1] if head else None
                q = self._cost(cost_critic, inputs, action, hidden)
        if q.dim() > 1:
            q = q.mean(dim=-1)
        return q.reshape(-1).double().cpu().numpy()

    # ---------------------------------------------------------- federated state
    @property
    def federated_keys(self) -> tuple[str, ...]:
        """Keys of :meth:`federated_state`, in a stable order."""
        return tuple(self.networks.state_dict())

    def federated_state(self) -> dict[str, Tensor]:
        """Detached contiguous CPU copies of all network parameters, online and target
        (``actor.layers.0.weight``, ``critic_target.layers.4.bias``, ...). Optimizer
        moments, the replay buffer and the noise stay private to the agent."""
        return self.networks.cpu_copy()

    def load_federated_state(self, state: dict[str, Tensor]) -> None:
        """Copy a :meth:`federated_state`-shaped dict in. Strict: a missing or unexpected
        key or a shape mismatch raises ``ValueError`` naming the key, changing nothing."""
        self.networks.load_strict(state)

    def set_proximal_anchor(self, mu: float) -> None:
        """FedProx (Li et al. 2020): from now on each update adds mu/2 ||w - w_anchor||^2 to
        both losses, w_anchor the online networks as they are now (the global model just
        loaded). ``mu`` = 0 removes the term."""
        pairs = [(self.actor_optimizer, self.actor), (self.critic_optimizer, self.critic)]
        if self.cost_critic_optimizer is not None:
            pairs.append((self.cost_critic_optimizer, self.networks.cost_critic))
        self.proximal.anchor(mu, dict(pairs))

    def sync_targets(self) -> None:
        """Hard-copy the online networks into the targets (e.g. after FedAvg of onlines)."""
        hard_update(self.networks.target_parameters(), self.networks.online_parameters())

    # -------------------------------------------------------------- checkpoints
    def save(self, path: Path, include_buffer: bool = False) -> None:
        """Write networks, optimizers, noise, counters and generators (and the buffer),
        atomically; the file loads with ``torch.load(weights_only=True)``."""
        checkpoint.write_checkpoint(checkpoint.agent_payload(self, include_buffer), path)

    def restore(self, path: Path) -> None:
        """Load a :meth:`save` file into this agent (same config and spaces): exact resume,
        with an empty buffer if none was saved. Raises ``CheckpointError``, changing
        nothing, for an unreadable or foreign file or one of another config or shapes."""
        checkpoint.restore_agent(self, path)

    @classmethod
    def from_checkpoint(  # a new agent with the file's config and seed, restored
        cls, path: Path, observation_space: spaces.Box | spaces.Dict | None = None,
        action_space: spaces.Box | None = None, device: str | torch.device = "cpu",
    ) -> DDPG:  # fmt: skip
        """Spaces left out are rebuilt from the file (the observation bounds unbounded)."""
        return checkpoint.load_agent(cls, path, observation_space, action_space, device)

    @checkpoint.class_only
    def load(cls, path: Path, device: str | torch.device = "cpu") -> DDPG:
        """A new agent from a :meth:`save` file or a run's ``models/*.pt``, as in SB3.
        Raises ``CheckpointError`` for an unreadable, foreign or malformed file."""
        return cls.from_checkpoint(path, device=device)
