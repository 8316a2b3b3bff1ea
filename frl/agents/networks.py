"""Actor and critic MLPs of DDPG, with a sparse-capable first layer or an encoder in front."""

from __future__ import annotations

import copy
import itertools
from collections.abc import Sequence
from typing import Any

import torch
from torch import Tensor, nn

from frl.agents.config import DDPGConfig
from frl.agents.observations import ObservationLayout
from frl.agents.precision import float32_layer
from frl.agents.sparse_linear import InputLinear, SparseRows
from frl.agents.vehicle_encoder import VehicleSetEncoder

FINAL_LAYER_INIT = 3e-3
"""Final layers start in U(-3e-3, 3e-3) so initial actions and Q-values are near zero
(Lillicrap et al. 2016, DDPG, Section 7)."""


def _hidden_stack(first: InputLinear, hidden_sizes: Sequence[int], out_features: int) -> list:
    layers: list[nn.Module] = [first]
    for fan_in, fan_out in itertools.pairwise(hidden_sizes):
        layers.append(nn.Linear(fan_in, fan_out))
    layers.append(nn.Linear(hidden_sizes[-1], out_features))
    return layers


def init_mlp_(layers: Sequence[nn.Module], generator: torch.Generator) -> None:
    """Initialise in place from ``generator`` only (never the global torch RNG).

    Hidden layers: ``nn.Linear``'s default U(-1/sqrt(fan_in), 1/sqrt(fan_in)) for weight
    and bias; final layer: U(-3e-3, 3e-3).
    """
    with torch.no_grad():
        for layer in layers[:-1]:
            if isinstance(layer, InputLinear):
                layer.reset_parameters(generator)
            else:
                bound = layer.in_features**-0.5
                layer.weight.uniform_(-bound, bound, generator=generator)
                layer.bias.uniform_(-bound, bound, generator=generator)
        layers[-1].weight.uniform_(-FINAL_LAYER_INIT, FINAL_LAYER_INIT, generator=generator)
        layers[-1].bias.uniform_(-FINAL_LAYER_INIT, FINAL_LAYER_INIT, generator=generator)


ACTOR_OUTPUTS: tuple[str, ...] = ("tanh", "clip")


class Actor(nn.Module):
    """Deterministic policy: flat observation -> action in [-1, 1].

    The output layer's value is bounded by ``tanh`` (DDPG's) or clipped to [-1, 1]
    (``clip``, for inverting-gradient updates: ``DDPGConfig.actor_update``). The agent maps
    [-1, 1] to the action bounds; keeping the network's range fixed keeps its state dict
    independent of the action space's bounds. With an ``encoder`` the MLP reads the
    encoder's output instead of the observation.
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        hidden_sizes: Sequence[int],
        encoder: nn.Module | None = None,
        output: str = "tanh",
    ) -> None:
        super().__init__()
        if output not in ACTOR_OUTPUTS:
            raise ValueError(f"output must be one of {ACTOR_OUTPUTS}, got {output!r}")
        self.output = output
        self.encoder = encoder
        in_features = obs_dim if encoder is None else encoder.out_features
        first = InputLinear(in_features, hidden_sizes[0])
        self.layers = nn.ModuleList(_hidden_stack(first, hidden_sizes, action_dim))

    def preactivation(self, obs: Tensor | SparseRows) -> Tensor:
        """The output layer's value before the bound (float32, also under autocast)."""
        x = obs if self.encoder is None else self.encoder(obs)
        for layer in self.layers[:-1]:
            x = torch.relu_(layer(x))  # in place: addmm's backward needs only its inputs
        return float32_layer(self.layers[-1], x)

    def forward(self, obs: Tensor | SparseRows) -> Tensor:
        preactivation = self.preactivation(obs)
        if self.output == "clip":
            return preactivation.clamp(-1.0, 1.0)
        return torch.tanh(preactivation)


class Critic(nn.Module):
    """Q(obs, action) with a linear output: returns reach -10 and below, so no tanh.

    The action joins the observation (or the encoder's output) at the first layer
    (``layers.0.extra_weight``), which computes ``Linear(in + action_dim, h0)`` on
    ``cat([x, action])``. With ``outputs`` > 1 it gives that many values per sample:
    the quantiles of the return (``DDPGConfig.critic.kind=quantile``).
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        hidden_sizes: Sequence[int],
        encoder: nn.Module | None = None,
        outputs: int = 1,
    ) -> None:
        super().__init__()
        self.encoder = encoder
        self.outputs = outputs
        in_features = obs_dim if encoder is None else encoder.out_features
        first = InputLinear(in_features, hidden_sizes[0], extra_features=action_dim)
        self.layers = nn.ModuleList(_hidden_stack(first, hidden_sizes, outputs))

    def forward(self, obs: Tensor | SparseRows, action: Tensor) -> Tensor:
        """Q-values (batch,), or (batch, outputs) where ``outputs`` > 1; float32 (also
        under autocast)."""
        return self.values_and_hidden(obs, action)[0]

    def values_and_hidden(self, obs: Tensor | SparseRows, action: Tensor) -> tuple[Tensor, Tensor]:
        """The Q-values of :meth:`forward` and the last hidden layer's activations they
        are read from (batch, ``hidden_sizes[-1]``), which a :class:`CostHead` reads."""
        x = obs if self.encoder is None else self.encoder(obs)
        # In place: addmm's backward needs only its inputs.
        x = torch.relu_(self.layers[0](x, action))
        for layer in self.layers[1:-1]:
            x = torch.relu_(layer(x))
        values = float32_layer(self.layers[-1], x)
        return (values.squeeze(-1) if self.outputs == 1 else values), x


class CostHead(nn.Module):
    """A collision budget's Q_c read from a critic's last hidden layer: one hidden layer
    as wide as that layer, ReLU, a linear output (``DDPGConfig.cost_critic=head``).

    It sees what the reward critic has learned to tell apart, crashes included, at the
    cost of a small MLP; the reward critic's trunk is not trained by its loss.
    """

    def __init__(self, in_features: int) -> None:
        super().__init__()
        self.layers = nn.ModuleList(
            [nn.Linear(in_features, in_features), nn.Linear(in_features, 1)]
        )

    def forward(self, hidden: Tensor) -> Tensor:
        """Q_c (batch,), float32 (also under autocast), from the critic's ``hidden``."""
        x = torch.relu(self.layers[0](hidden))
        return float32_layer(self.layers[-1], x).squeeze(-1)


NETWORK_NAMES: tuple[str, ...] = ("actor", "critic", "actor_target", "critic_target")
"""The networks of :class:`ActorCritic`, the first part of its state-dict keys."""
COST_NETWORK_NAMES: tuple[str, ...] = ("cost_critic", "cost_critic_target")
"""The cost critic and its target, where the agent has a collision budget."""
TARGET_NAMES: tuple[str, ...] = ("actor_target", "critic_target", "cost_critic_target")


class ActorCritic(nn.Module):
    """DDPG's four networks: actor, critic and their slowly following targets; with a
    ``cost_critic`` (a collision budget: a :class:`Critic`, or a :class:`CostHead` on the
    critic) that and its target too.

    Its ``state_dict()`` keys are ``actor.layers.0.weight``, ``critic_target.layers.4.bias``
    and so on: what FedAvg averages, checkpoints hold and the Flower wire carries.
    """

    def __init__(
        self, actor: Actor, critic: Critic, cost_critic: Critic | CostHead | None = None
    ) -> None:
        super().__init__()
        self.actor = actor
        self.critic = critic
        self.actor_target = copy.deepcopy(actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(critic).requires_grad_(False)
        self.cost_critic = cost_critic
        self.cost_critic_target = (
            None if cost_critic is None else copy.deepcopy(cost_critic).requires_grad_(False)
        )

    @property
    def names(self) -> tuple[str, ...]:
        """The networks this agent has, online before target within each kind."""
        return NETWORK_NAMES + (COST_NETWORK_NAMES if self.cost_critic is not None else ())

    def online_parameters(self) -> list[nn.Parameter]:
        return [
            parameter
            for name in self.names
            if name not in TARGET_NAMES
            for parameter in getattr(self, name).parameters()
        ]

    def target_parameters(self) -> list[nn.Parameter]:
        """In the order of :meth:`online_parameters`, each target beside its network."""
        return [
            parameter
            for name in self.names
            if name not in TARGET_NAMES
            for parameter in getattr(self, f"{name}_target").parameters()
        ]

    def networks(self) -> dict[str, nn.Module]:
        """The networks by name: :data:`NETWORK_NAMES`, then the cost critic's."""
        return {name: getattr(self, name) for name in self.names}

    def cpu_copy(self) -> dict[str, Tensor]:
        """Detached contiguous CPU copies of every tensor of ``state_dict()``."""
        return {
            key: tensor.detach().to("cpu", memory_format=torch.contiguous_format, copy=True)
            for key, tensor in self.state_dict().items()
        }

    def load_strict(self, state: dict[str, Tensor]) -> None:
        """Copy a ``state_dict()``-shaped dict into the networks, in place.

        Raises:
            ValueError: a missing or unexpected key, or a shape mismatch (naming the key);
                nothing is modified then.
        """
        self.check_state(state)
        self.load_state_dict(state)

    def check_state(self, state: dict[str, Tensor]) -> None:
        """Raise ``ValueError`` naming the first key that ``state`` lacks, has extra or
        holds in another shape than ``state_dict()``."""
        expected = self.state_dict()
        missing = [key for key in expected if key not in state]
        if missing:
            raise ValueError(f"the networks' state lacks {missing[0]!r} ({len(missing)} missing)")
        unexpected = [key for key in state if key not in expected]
        if unexpected:
            raise ValueError(f"the networks' state has unexpected key {unexpected[0]!r}")
        for key, tensor in expected.items():
            value = state[key]
            if not isinstance(value, Tensor) or value.shape != tensor.shape:
                shape = tuple(value.shape) if isinstance(value, Tensor) else type(value).__name__
                raise ValueError(f"{key!r}: expected shape {tuple(tensor.shape)}, got {shape}")


def build_network(
    kind: type[Actor] | type[Critic], obs_dim: int, action_dim: int, config: DDPGConfig,
    layout: ObservationLayout, generator: torch.Generator, device: torch.device,
    outputs: int = 1,
) -> Actor | Critic:  # fmt: skip
    """An actor or critic as ``config`` describes it, initialised from ``generator`` alone;
    a critic with ``outputs`` values per sample (quantiles) where asked.

    Built on the meta device so that nn.Linear's own init never draws from the global
    torch RNG; then materialised and initialised from ``generator`` only.
    """
    encoder = None
    if config.encoder == "vehicles":
        encoder = VehicleSetEncoder(layout.grid_shape, config.encoder_width, layout.extra_features)
    options: dict[str, object] = {}
    if kind is Actor and config.actor_update != "tanh":
        options["output"] = "clip"
    if kind is Critic and outputs > 1:
        options["outputs"] = outputs
    with torch.device("meta"):
        network = kind(obs_dim, action_dim, config.hidden_sizes, encoder, **options)
    network = network.to_empty(device="cpu")
    if network.encoder is not None:
        network.encoder.reset_parameters(generator)
    init_mlp_(network.layers, generator)
    return network.to(device)


def build_cost_head(
    config: DDPGConfig, generator: torch.Generator, device: torch.device
) -> CostHead:
    """A :class:`CostHead` on a critic as ``config`` describes it, initialised from
    ``generator`` alone (as :func:`build_network`)."""
    with torch.device("meta"):
        head = CostHead(config.hidden_sizes[-1])
    head = head.to_empty(device="cpu")
    init_mlp_(head.layers, generator)
    return head.to(device)


def build_actor_critic(
    config: DDPGConfig, obs_dim: int, action_dim: int, layout: ObservationLayout,
    generator: torch.Generator, device: torch.device,
) -> ActorCritic:  # fmt: skip
    """The agent's networks as ``config`` describes them, initialised from ``generator``
    in a fixed order: actor, critic (``quantiles`` outputs for a quantile critic), then a
    collision budget's cost critic (a head or a separate critic), built last so that the
    actor's and critic's initial weights do not depend on it."""

    def network(kind: type[Actor] | type[Critic], outputs: int = 1) -> Any:
        return build_network(kind, obs_dim, action_dim, config, layout, generator, device, outputs)

    actor = network(Actor)
    critic = network(Critic, config.critic.quantiles if config.critic.kind == "quantile" else 1)
    cost_critic: Critic | CostHead | None = None
    if config.costed:
        separate = config.cost_critic == "separate"
        cost_critic = network(Critic) if separate else build_cost_head(config, generator, device)
    return ActorCritic(actor, critic, cost_critic)


class DeviceAdam(torch.optim.Adam):
    """Adam that keeps the ``capturable`` it was built with when a state is loaded: a
    checkpoint written on a CPU resumes on a GPU, whose captured update
    (:mod:`frl.agents.update_graph`) needs a capturable step, and one written on a GPU
    resumes on a CPU."""

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        capturable = [group["capturable"] for group in self.param_groups]
        super().load_state_dict(state_dict)
        for group, flag in zip(self.param_groups, capturable, strict=True):
            group["capturable"] = flag
            for param in group["params"] if flag else ():
                state = self.state.get(param, {})
                if isinstance(state.get("step"), Tensor):  # a capturable step counts on the device
                    state["step"] = state["step"].to(param.device, torch.float32)


def make_adam(params: list[nn.Parameter], lr: float, device: torch.device) -> torch.optim.Adam:
    """Adam with the fused kernel, which updates all parameters in one pass (on CPU since
    torch 2.4), else the foreach one; on a GPU capturable, so that an update can be
    captured as a CUDA graph (its step count lives on the device)."""
    capturable = device.type == "cuda"
    try:
        return DeviceAdam(params, lr=lr, fused=True, capturable=capturable)
    except (RuntimeError, TypeError, ValueError):
        return DeviceAdam(
            params, lr=lr, foreach=device.type != "cpu" or None, capturable=capturable
        )
