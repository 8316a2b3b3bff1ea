"""The roadside unit's aggregation strategies, as pure maths over parameter dicts.

Each strategy turns the round's uploads (and, for server-side optimisers, the global
model the round started from) into the next global model. The maths follows the
strategies Flower ships (``flwr.serverapp.strategy``, Flower 1.41), parameter names and
defaults included, so ``federation.backend=flower``, which runs Flower's own classes
(:mod:`frl.flower.strategies`), and the processes backend compute the same global model
(tests/test_federation_strategies.py). Sums run in float64 and are cast back.

- ``fedavg``: the weighted mean, Eq. (3).
- ``fedprox``: the weighted mean; each vehicle adds mu/2 ||w - w_global||^2 to its critic
  and actor losses (``proximal_mu`` 0.0).
- ``fedavgm``: w - lr * m with m = momentum * m + (w - mean) (``server_learning_rate``
  1.0, ``server_momentum`` 0.0).
- ``fedadam``: Adam on delta = mean - w, bias-corrected (``eta`` 0.1, ``eta_l`` 0.1,
  ``beta_1`` 0.9, ``beta_2`` 0.99, ``tau`` 1e-3).
- ``fedyogi``: Yogi on delta (``eta`` 0.01, ``eta_l`` 0.0316, ``beta_1`` 0.9, ``beta_2``
  0.99, ``tau`` 1e-3).
- ``fedadagrad``: Adagrad on delta (``eta`` 0.1, ``eta_l`` 0.1, ``tau`` 1e-3).
- ``fedmedian``: the coordinate-wise median (unweighted).
- ``fedtrimmedavg``: the coordinate-wise mean without the ``beta`` share at each end
  (unweighted; ``beta`` 0.2).

``eta_l`` (the clients' learning rate in Reddi et al. 2021) is accepted for parity with
Flower and not used: a vehicle's optimiser is its agent's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import torch
from torch import Tensor

from frl.federation.averaging import fedavg

STRATEGY_PARAMETERS: dict[str, dict[str, float]] = {
    "fedavg": {},
    "fedprox": {"proximal_mu": 0.0},
    "fedavgm": {"server_learning_rate": 1.0, "server_momentum": 0.0},
    "fedadam": {"eta": 1e-1, "eta_l": 1e-1, "beta_1": 0.9, "beta_2": 0.99, "tau": 1e-3},
    "fedyogi": {"eta": 1e-2, "eta_l": 0.0316, "beta_1": 0.9, "beta_2": 0.99, "tau": 1e-3},
    "fedadagrad": {"eta": 1e-1, "eta_l": 1e-1, "tau": 1e-3},
    "fedmedian": {},
    "fedtrimmedavg": {"beta": 0.2},
}
"""Each strategy's parameters and their defaults (Flower's)."""

PARAMETER_RANGES: dict[str, tuple[Any, str]] = {
    "proximal_mu": (lambda v: v >= 0, ">= 0"),
    "server_learning_rate": (lambda v: v > 0, "> 0"),
    "server_momentum": (lambda v: 0 <= v < 1, "in [0, 1)"),
    "eta": (lambda v: v > 0, "> 0"),
    "beta_1": (lambda v: 0 <= v < 1, "in [0, 1)"),
    "beta_2": (lambda v: 0 <= v < 1, "in [0, 1)"),
    "tau": (lambda v: v > 0, "> 0"),
    "beta": (lambda v: 0 <= v < 0.5, "in [0, 0.5)"),
}
"""The valid values of each parameter that has bounds (predicate, as said in the error)."""

STRATEGIES: tuple[str, ...] = tuple(STRATEGY_PARAMETERS)
SERVER_OPTIMIZERS: tuple[str, ...] = ("fedavgm", "fedadam", "fedyogi", "fedadagrad")
"""Strategies that step from the previous global model, so need one to start from."""


@dataclass(frozen=True)
class StrategySpec:
    """A strategy by name with its parameters; unknown names and parameters are refused."""

    name: str = "fedavg"
    params: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.name not in STRATEGY_PARAMETERS:
            raise ValueError(
                f"unknown federation.strategy {self.name!r}; choose one of {', '.join(STRATEGIES)}"
            )
        allowed = STRATEGY_PARAMETERS[self.name]
        for key, value in dict(self.params).items():
            if key not in allowed:
                takes = ", ".join(allowed) or "no parameters"
                raise ValueError(f"federation.strategy={self.name} takes {takes}; got {key!r}")
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not (math.isfinite(value))
            ):
                raise ValueError(
                    f"federation.strategy_params.{key} must be a number, got {value!r}"
                )
        resolved = {**allowed, **{k: float(v) for k, v in dict(self.params).items()}}
        for key, value in resolved.items():
            within, text = PARAMETER_RANGES.get(key, (lambda _: True, ""))
            if not within(value):
                raise ValueError(f"federation.strategy_params.{key} must be {text}, got {value!r}")
        object.__setattr__(self, "params", resolved)

    @property
    def needs_global_model(self) -> bool:
        """Whether it steps from the previous global model (a server-side optimiser)."""
        return self.name in SERVER_OPTIMIZERS

    @property
    def proximal_mu(self) -> float:
        """The vehicles' proximal weight (FedProx); 0 for every other strategy."""
        return float(self.params.get("proximal_mu", 0.0))


class Aggregator(Protocol):
    """What the roadside unit needs of a strategy: :class:`ServerStrategy`, or Flower's
    classes behind :class:`frl.flower.strategies.FlowerServerStrategy`."""

    spec: StrategySpec

    def aggregate(
        self,
        uploads: Sequence[Mapping[str, Tensor]],
        weights: Sequence[float] | None,
        current: Mapping[str, Tensor] | None,
        server_round: int,
    ) -> dict[str, Tensor]:
        """The next global model from the round's uploads."""

    def state_dict(self) -> dict[str, Tensor]:
        """The state carried from round to round, as flat tensors."""

    def load_state_dict(self, flat: Mapping[str, Tensor]) -> None:
        """Restore :meth:`state_dict`."""


class ServerStrategy:
    """The processes backend's roadside unit: :class:`StrategySpec`'s maths, with the
    server state (momentum, moments) kept for checkpoints."""

    def __init__(self, spec: StrategySpec) -> None:
        self.spec = spec
        self.state: dict[str, dict[str, Tensor]] = {}
        """``momentum`` (fedavgm), ``m`` and ``v`` (fedadam, fedyogi, fedadagrad)."""

    def aggregate(
        self,
        uploads: Sequence[Mapping[str, Tensor]],
        weights: Sequence[float] | None,
        current: Mapping[str, Tensor] | None,
        server_round: int,
    ) -> dict[str, Tensor]:
        """The next global model from the round's ``uploads``.

        Args:
            weights: per-upload weights of the mean (None: equal).
            current: the global model the round started from (server optimisers).
            server_round: 1 for the first aggregation (FedAdam's bias correction).
        """
        name, p = self.spec.name, self.spec.params
        if name == "fedmedian":
            return _coordinatewise(uploads, _median)
        if name == "fedtrimmedavg":
            return _coordinatewise(uploads, lambda stack: _trimmed_mean(stack, p["beta"]))
        mean = fedavg(uploads, weights)
        if name not in SERVER_OPTIMIZERS:
            return mean
        if current is None:
            raise RuntimeError(f"{name} needs the previous global model to step from")
        new: dict[str, Tensor] = {}
        for key, averaged in mean.items():
            if not averaged.is_floating_point():
                new[key] = averaged
                continue
            x = current[key].to(torch.float64)
            delta = averaged.to(torch.float64) - x
            new[key] = self._step(key, x, delta, server_round).to(averaged.dtype)
        return new

    def _step(self, key: str, x: Tensor, delta: Tensor, server_round: int) -> Tensor:
        name, p = self.spec.name, self.spec.params
        if name == "fedavgm":
            gradient = -delta  # the pseudo-gradient: previous minus averaged
            if p["server_momentum"] > 0:
                momentum = self.state.setdefault("momentum", {})
                previous = momentum.get(key)
                gradient = (
                    gradient if previous is None else p["server_momentum"] * previous + gradient
                )
                momentum[key] = gradient
            return x - p["server_learning_rate"] * gradient
        beta_1 = p.get("beta_1", 0.0)  # FedAdagrad keeps Flower's FedOpt default, 0
        m_all, v_all = self.state.setdefault("m", {}), self.state.setdefault("v", {})
        m = beta_1 * m_all.get(key, torch.zeros_like(x)) + (1 - beta_1) * delta
        v = v_all.get(key, torch.zeros_like(x))
        square = delta**2
        if name == "fedadam":
            v = p["beta_2"] * v + (1 - p["beta_2"]) * square
            eta = (
                p["eta"]
                * math.sqrt(1 - p["beta_2"] ** (server_round + 1.0))
                / (1 - beta_1 ** (server_round + 1.0))
            )
        elif name == "fedyogi":
            v = v - (1.0 - p["beta_2"]) * square * torch.sign(v - square)
            eta = p["eta"]
        else:  # fedadagrad
            v = v + square
            eta = p["eta"]
        m_all[key], v_all[key] = m, v
        return x + eta * m / (torch.sqrt(v) + p["tau"])

    def state_dict(self) -> dict[str, Tensor]:
        """The server state as flat tensors (``m/actor.0.weight``), for checkpoints."""
        return {
            f"{part}/{key}": t for part, tensors in self.state.items() for key, t in tensors.items()
        }

    def load_state_dict(self, flat: Mapping[str, Tensor]) -> None:
        """Restore :meth:`state_dict`."""
        self.state = {}
        for name, tensor in flat.items():
            part, key = name.split("/", 1)
            self.state.setdefault(part, {})[key] = tensor.to(torch.float64)


def _coordinatewise(uploads: Sequence[Mapping[str, Tensor]], reduce: Any) -> dict[str, Tensor]:
    """``reduce`` over the clients of each parameter (checked as :func:`fedavg` checks)."""
    fedavg(uploads)  # the same names, shapes and dtypes in every upload, or ValueError
    result: dict[str, Tensor] = {}
    for key, first in uploads[0].items():
        if not first.is_floating_point():
            result[key] = first.detach().cpu().clone()
            continue
        stack = torch.stack([u[key].detach().cpu().to(torch.float64) for u in uploads])
        result[key] = reduce(stack).to(first.dtype)
    return result


def _trimmed_mean(stack: Tensor, beta: float) -> Tensor:
    """Mean over dim 0 without the floor(beta * n) smallest and largest values, as
    Flower's ``trim_mean`` (after SciPy's)."""
    count = stack.shape[0]
    cut = int(beta * count)
    ordered = stack.sort(dim=0).values
    return ordered[cut : count - cut].mean(dim=0)


def _median(stack: Tensor) -> Tensor:
    """NumPy's median over dim 0: the mean of the two middle values for an even count
    (``torch.median`` takes the lower one)."""
    ordered = stack.sort(dim=0).values
    count = stack.shape[0]
    middle = count // 2
    return ordered[middle] if count % 2 else (ordered[middle - 1] + ordered[middle]) / 2
