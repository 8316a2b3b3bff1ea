"""The agent's side of federated learning: its networks as one flat state_dict (what FedAvg
averages, a plain tensor mean), the targets' copy after an average, and FedProx's pull."""

from __future__ import annotations

from typing import Any

from torch import Tensor

from frl.agents.functional import ProximalPull, hard_update
from frl.agents.networks import TARGET_NAMES, ActorCritic


def is_target_key(name: str) -> bool:
    """Whether a federated-state key belongs to a target network."""
    return name.startswith(tuple(f"{target}." for target in TARGET_NAMES))


class FederatedAgent:
    """What :class:`frl.agents.DDPG` offers a federation, read from its ``networks``, its
    optimizers, its ``constraint`` and its ``proximal`` pull."""

    networks: ActorCritic
    proximal: ProximalPull
    actor_optimizer: Any
    critic_optimizer: Any
    constraint: Any

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
        every loss, w_anchor the online networks as they are now (the global model just
        loaded). ``mu`` = 0 removes the term."""
        nets = self.networks
        pairs = [(self.actor_optimizer, nets.actor), (self.critic_optimizer, nets.critic)]
        if self.constraint is not None:
            pairs.append((self.constraint.optimizer, nets.cost_critic))
        self.proximal.anchor(mu, dict(pairs))

    def sync_targets(self) -> None:
        """Hard-copy the online networks into the targets (e.g. after FedAvg of onlines)."""
        hard_update(self.networks.target_parameters(), self.networks.online_parameters())
