"""Federated training: FedAvg, the vehicles, their worker processes and the roadside unit.

- :func:`fedavg`: the pure Eq. (3) average of parameter dicts.
- :class:`VehicleClient`: env + agent + local training, independent of transport.
- :class:`WorkerPool` / :class:`ProcessClientPool`: one spawned process per client,
  spoken to in the frames of :mod:`frl.federation.vehicle_host`, as Flower's vehicles are.
- :class:`Coordinator`: the roadside unit's rounds, aggregation, logging, checkpoints.
- :class:`FederationPlan`: the schemes ``central``, ``separate``, ``fedavg``.

The Flower backend lives beside this package, in :mod:`frl.flower`.
"""

import importlib
from typing import Any

# Exported names and the module each lives in. Loaded on first use (PEP 562), so that
# the messaging modules a vehicle's relay imports (frames, vehicle_host) stay free of
# torch and SUMO: importing frl.federation.frames runs this file first.
_EXPORTS: dict[str, str] = {
    "ClientSpec": "client", "LocalUpdate": "client", "VehicleClient": "client",
    "ClientPool": "client_pool", "ProcessClientPool": "client_pool",
    "Coordinator": "coordinator",
    "TARGET_MODES": "averaging", "WEIGHTINGS": "averaging", "fedavg": "averaging",
    "state_nbytes": "averaging",
    "FEDERATION_BACKENDS": "plan", "SCHEMES": "plan", "FederationPlan": "plan",
    "client_seeds": "plan", "evaluation_seeds": "plan",
    "ClientFailure": "workers", "WorkerPool": "workers", "threads_per_worker": "workers",
}  # fmt: skip


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'frl.federation' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"frl.federation.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value


__all__ = [
    "FEDERATION_BACKENDS",
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
    "VehicleClient",
    "WorkerPool",
    "client_seeds",
    "evaluation_seeds",
    "fedavg",
    "state_nbytes",
    "threads_per_worker",
]
