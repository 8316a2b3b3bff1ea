"""Federated averaging of model parameters, the paper's Eq. (3), as a pure function."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

TARGET_MODES: tuple[str, ...] = ("average", "resync")
"""How target networks follow aggregation: :attr:`frl.federation.FederationPlan.targets`."""

WEIGHTINGS: tuple[str, ...] = ("equal", "steps")
"""Client weights of FedAvg: equal (Eq. (3)) or by environment steps in the round."""


def fedavg(
    states: Sequence[Mapping[str, Tensor]], weights: Sequence[float] | None = None
) -> dict[str, Tensor]:
    """The weighted mean of client parameter dicts: w_agg = sum_i p_i w_i, p_i = weight_i / sum.

    With ``weights=None`` every client weighs 1/N, exactly Eq. (3) of the paper. Passing
    per-client step counts weighs clients by the experience behind their model, as the
    original FedAvg (McMahan et al. 2017) weighs by example count.

    - Keys are matched by name; every client must hold the same keys, and each key the
      same shape and dtype in every client, else ``ValueError`` naming key and client.
    - Floating-point tensors are averaged in float64 and cast back to their own dtype.
      Other tensors (integer counters, flags) are not averaged: the first client's value
      is taken.
    - Inputs are never modified; the result holds new CPU tensors, keyed in the first
      client's order.
    """
    if len(states) == 0:
        raise ValueError("fedavg needs at least one client state")
    coefficients = _normalised_weights(len(states), weights)
    reference = states[0]
    reference_keys = set(reference)
    for index, state in enumerate(states[1:], start=1):
        keys = set(state)
        if keys != reference_keys:
            missing = sorted(reference_keys - keys)
            extra = sorted(keys - reference_keys)
            detail = f"lacks {missing[0]!r}" if missing else f"has unexpected {extra[0]!r}"
            raise ValueError(
                f"client {index} {detail}: all clients must send the same parameter names "
                f"({len(missing)} missing, {len(extra)} unexpected)"
            )
    result: dict[str, Tensor] = {}
    for key, first in reference.items():
        if not isinstance(first, Tensor):
            raise TypeError(f"{key!r} of client 0 is a {type(first).__name__}, not a Tensor")
        for index, state in enumerate(states[1:], start=1):
            other = state[key]
            if not isinstance(other, Tensor):
                raise TypeError(f"{key!r} of client {index} is a {type(other).__name__}")
            if other.shape != first.shape:
                raise ValueError(
                    f"{key!r}: client {index} has shape {tuple(other.shape)}, "
                    f"client 0 has {tuple(first.shape)}"
                )
            if other.dtype != first.dtype:
                raise ValueError(
                    f"{key!r}: client {index} has dtype {other.dtype}, client 0 has {first.dtype}"
                )
        if not first.is_floating_point():
            result[key] = first.detach().cpu().clone()
            continue
        total = torch.zeros(first.shape, dtype=torch.float64)
        for coefficient, state in zip(coefficients, states, strict=True):
            total.add_(state[key].detach().cpu().to(torch.float64), alpha=coefficient)
        result[key] = total.to(first.dtype)
    return result


def _normalised_weights(count: int, weights: Sequence[float] | None) -> list[float]:
    if weights is None:
        return [1.0 / count] * count
    if len(weights) != count:
        raise ValueError(f"got {len(weights)} weights for {count} client states")
    values = [float(w) for w in weights]
    if not all(math.isfinite(w) and w >= 0 for w in values):
        raise ValueError(f"weights must be finite and non-negative, got {values}")
    total = sum(values)
    if total <= 0:
        raise ValueError("weights must not all be zero")
    return [w / total for w in values]


def state_nbytes(state: Mapping[str, Tensor]) -> int:
    """Bytes of tensor data in a parameter dict: what one upload or download carries."""
    return sum(t.numel() * t.element_size() for t in state.values())
