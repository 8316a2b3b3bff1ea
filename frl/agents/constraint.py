"""A collision budget, one part of the agent (``DDPGConfig.collision_budget``).

Safe RL's constraint on DDPG (Stooke, Achiam and Abbeel 2020; OmniSafe's DDPG-Lag): a
cost critic learns Q_c, the discounted collisions to come, and a Lagrange multiplier
lambda prices it in the actor's objective, following the collision rate of the episodes
the budget counts. The agent calls this part at four points:

- acting: :meth:`CollisionConstraint.observe_cost` and
  :meth:`~CollisionConstraint.episode_ends` (the count behind the multiplier);
- learning: :meth:`~CollisionConstraint.losses` (the cost critic's loss on the batch, which
  the agent descends with :attr:`~CollisionConstraint.optimizer`) and
  :meth:`~CollisionConstraint.price` (the actor's objective under the budget).

The cost networks themselves live in :class:`~frl.agents.networks.ActorCritic` beside the
others, so FedAvg, targets and checkpoints treat every network alike.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from frl.agents.config import DDPGConfig
from frl.agents.functional import td_target
from frl.agents.lagrange import PIDLagrangian
from frl.agents.networks import ActorCritic, CostHead, Critic, make_adam
from frl.agents.replay_buffer import Batch
from frl.agents.sparse_linear import SparseRows


class CollisionConstraint:
    """The cost critic's optimizer, the PID multiplier and the running episode's count,
    for the cost networks of ``networks`` (which must have them).

    Args:
        config: the agent's config, with ``collision_budget`` set.
        networks: the agent's networks, a cost critic among them.
        device: where the cost critic's optimizer state lives.
        autocast: the agent's precision context for forward passes.
    """

    def __init__(
        self,
        config: DDPGConfig,
        networks: ActorCritic,
        device: torch.device,
        autocast: Callable[[], Any],
    ) -> None:
        if networks.cost_critic is None or config.collision_budget is None:
            raise ValueError("a collision constraint needs collision_budget and a cost critic")
        self.networks = networks
        self.autocast = autocast
        self.optimizer = make_adam(
            list(networks.cost_critic.parameters()), config.critic_lr, device
        )
        """The cost critic's Adam, at the reward critic's rate."""
        self.lagrangian = PIDLagrangian(
            config.collision_budget, config.lagrange_gains, config.lagrange_window
        )
        """The multiplier (:mod:`frl.agents.lagrange`)."""
        self.episode_cost, self.episode_steps = 0.0, 0
        """The running training episode's collisions and steps. Every training episode
        counts, exploration noise and all: counting only noise-free ones was measured and
        retired (docs/studies.md, "A budget the car can keep")."""
        self.multiplier_now = torch.zeros((), device=device)
        """lambda on the device, and 1 + lambda (rounded once, from float64, as Python's
        ``1.0 + lambda`` is): what :meth:`price` reads, so that an update captured as a
        graph reads today's multiplier, not the one it was captured with. Refilled in
        place whenever the multiplier moves."""
        self.price_denominator = torch.ones((), device=device)

    @property
    def reads_critic_hidden(self) -> bool:
        """Whether Q_c is a head on the reward critic's last hidden layer."""
        return isinstance(self.networks.cost_critic, CostHead)

    # ------------------------------------------------------------------ acting
    def observe_cost(self, cost: float) -> None:
        """One step of the running training episode, with ``cost`` collisions."""
        self.episode_cost += cost
        self.episode_steps += 1

    def episode_ends(self) -> None:
        """The running training episode ended: the multiplier follows it (nothing if no
        step was counted since the last end)."""
        if self.episode_steps:
            self.lagrangian.episode_end(self.episode_cost)
            self._refresh_multiplier()
        self.episode_cost, self.episode_steps = 0.0, 0

    def _refresh_multiplier(self) -> None:
        multiplier = self.lagrangian.multiplier
        self.multiplier_now.fill_(multiplier)
        self.price_denominator.fill_(1.0 + multiplier)

    def stats(self) -> dict[str, float]:
        """The multiplier, and the rate it follows once an episode has ended."""
        stats = {"lagrange_multiplier": self.lagrangian.multiplier}
        if self.lagrangian.recent:
            stats["collision_rate"] = self.lagrangian.collision_rate
        return stats

    # ---------------------------------------------------------------- learning
    def values(
        self, network: Critic | CostHead, obs: Tensor | SparseRows, action: Tensor,
        hidden: Tensor | None,
    ) -> Tensor:  # fmt: skip
        """Q_c of ``network`` (online or target) at ``(obs, action)``: a separate cost
        critic reads them, a cost head the reward critic's last hidden layer there."""
        if isinstance(network, CostHead):
            assert hidden is not None
            return network(hidden)
        return network(obs, action)

    def losses(
        self, batch: Batch, next_actions: Tensor, discount: float | Tensor, hidden: Tensor,
        next_hidden: Tensor,
    ) -> tuple[Tensor, dict[str, Tensor]]:  # fmt: skip
        """The cost critic's loss on ``batch`` (forward only): squared error to the n-step
        TD target of the discounted collisions to come, bootstrapped from its own target
        network; where the batch carries an episode's cost to its end
        (``Batch.costs_final``), that cost is the target. ``hidden``, ``next_hidden``: the
        last hidden layers of the critic at the batch and of the target critic at the next
        states, detached (what a cost head reads)."""
        nets = self.networks
        assert nets.cost_critic is not None and nets.cost_critic_target is not None
        assert batch.costs is not None
        with self.autocast(), torch.no_grad():
            next_cost = self.values(
                nets.cost_critic_target, batch.next_obs, next_actions, next_hidden
            )
        with self.autocast():
            cost_q = self.values(nets.cost_critic, batch.obs, batch.actions, hidden)
        ends = batch.terminated
        if batch.costs_final is not None:
            ends = torch.maximum(ends, batch.costs_final)
        loss = F.mse_loss(cost_q, td_target(batch.costs, ends, next_cost, discount))
        return loss, {"cost_critic_loss": loss.detach(), "cost_q_mean": cost_q.detach().mean()}

    def price(
        self, value: Tensor, obs: Tensor | SparseRows, action: Tensor, hidden: Tensor | None,
        multiplier: tuple[Tensor, Tensor] | None = None,
    ) -> Tensor:  # fmt: skip
        """The actor's objective under the budget: (value - lambda Q_c) / (1 + lambda), so
        that its scale stays that of a return as lambda grows (Stooke et al. 2020).
        ``multiplier``: lambda and 1 + lambda as tensors (None: this constraint's own,
        :attr:`multiplier_now` and :attr:`price_denominator`)."""
        assert self.networks.cost_critic is not None
        with self.autocast():
            cost = self.values(self.networks.cost_critic, obs, action, hidden)
        now, denominator = (
            (self.multiplier_now, self.price_denominator) if multiplier is None else multiplier
        )
        return (value - now * cost) / denominator

    # ------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        """The multiplier and the running episode's count, as checkpoints keep them (the
        optimizer's state is saved beside the agent's others)."""
        return {
            "multiplier": self.lagrangian.state_dict(),
            "episode_cost": self.episode_cost,
            "episode_steps": self.episode_steps,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.lagrangian.load_state_dict(state["multiplier"])
        self._refresh_multiplier()
        self.episode_cost = float(state["episode_cost"])
        self.episode_steps = int(state["episode_steps"])
