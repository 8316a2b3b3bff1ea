"""Actor and critic MLPs of DDPG, with a sparse-capable first layer or an encoder in front."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import torch
from torch import Tensor, nn

from frl.agents.precision import float32_layer
from frl.agents.sparse_linear import InputLinear, SparseRows

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
    ``cat([x, action])``. With ``layer_norm`` each hidden layer's output is normalised
    (``norms.i``) before its ReLU.
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        hidden_sizes: Sequence[int],
        encoder: nn.Module | None = None,
        layer_norm: bool = False,
    ) -> None:
        super().__init__()
        self.encoder = encoder
        in_features = obs_dim if encoder is None else encoder.out_features
        first = InputLinear(in_features, hidden_sizes[0], extra_features=action_dim)
        self.layers = nn.ModuleList(_hidden_stack(first, hidden_sizes, 1))
        self.norms = (
            nn.ModuleList(nn.LayerNorm(width) for width in hidden_sizes) if layer_norm else None
        )

    def forward(self, obs: Tensor | SparseRows, action: Tensor) -> Tensor:
        """Q-values, float32 (also under autocast)."""
        x = obs if self.encoder is None else self.encoder(obs)
        x = self._activated(0, self.layers[0](x, action))
        for index, layer in enumerate(self.layers[1:-1], start=1):
            x = self._activated(index, layer(x))
        return float32_layer(self.layers[-1], x).squeeze(-1)

    def _activated(self, index: int, x: Tensor) -> Tensor:
        """ReLU of hidden layer ``index``'s output, after its LayerNorm if there is one.

        In place: addmm's and layer_norm's backward passes need only their inputs."""
        return torch.relu_(x if self.norms is None else self.norms[index](x))
