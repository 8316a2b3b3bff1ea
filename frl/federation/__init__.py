"""Federated training: FedAvg, the vehicles, their worker processes and the roadside unit.

- :func:`fedavg`: the pure Eq. (3) average of parameter dicts.
- :class:`VehicleClient`: env + agent + local training, independent of transport.
- :class:`WorkerPool` / :class:`ProcessClientPool`: one spawned process per client.
- :class:`Coordinator`: the roadside unit's rounds, aggregation, logging, checkpoints.
- :class:`FederationPlan`: the schemes ``central``, ``separate``, ``fedavg``.
- :mod:`frl.federation.flower`: the Flower backend (``pip install frl[flower]``).

Names are imported on first use, so that a submodule (a Flower ClientApp, started
afresh for every message) can be imported without torch and SUMO.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS: dict[str, str] = {
    "ClientSpec": "client",
    "LocalUpdate": "client",
    "VehicleClient": "client",
    "Coordinator": "coordinator",
    "RunState": "coordinator",
    "TARGET_MODES": "fedavg",
    "WEIGHTINGS": "fedavg",
    "fedavg": "fedavg",
    "state_nbytes": "fedavg",
    "BACKENDS": "plan",
    "SCHEMES": "plan",
    "FederationPlan": "plan",
    "client_seeds": "plan",
    "evaluation_seeds": "plan",
    "ClientPool": "pool",
    "ProcessClientPool": "pool",
    "ClientFailure": "workers",
    "WorkerPool": "workers",
    "threads_per_worker": "workers",
}

__all__ = [
    "BACKENDS",
    "SCHEMES",
    "TARGET_MODES",
    "WEIGHTINGS",
    "ClientFailure",
    "ClientPool",
    "ClientSpec",
    "Coordinator",
    "FederationPlan",
    "LocalUpdate",
    "ProcessClientPool",
    "RunState",
    "VehicleClient",
    "WorkerPool",
    "client_seeds",
    "evaluation_seeds",
    "fedavg",
    "state_nbytes",
    "threads_per_worker",
]

if TYPE_CHECKING:
    from frl.federation.client import ClientSpec, LocalUpdate, VehicleClient
    from frl.federation.coordinator import Coordinator, RunState
    from frl.federation.fedavg import TARGET_MODES, WEIGHTINGS, fedavg, state_nbytes
    from frl.federation.plan import (
        BACKENDS,
        SCHEMES,
        FederationPlan,
        client_seeds,
        evaluation_seeds,
    )
    from frl.federation.pool import ClientPool, ProcessClientPool
    from frl.federation.workers import ClientFailure, WorkerPool, threads_per_worker


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'frl.federation' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"frl.federation.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])
