"""Federated training: FedAvg, the vehicles, their worker processes and the roadside unit.

- :func:`fedavg`: the pure Eq. (3) average of parameter dicts.
- :class:`VehicleClient`: env + agent + local training, independent of transport.
- :class:`WorkerPool` / :class:`ProcessClientPool`: one spawned process per client,
  spoken to in the frames of :mod:`frl.vehicle_host`, as Flower's vehicles are.
- :class:`Coordinator`: the roadside unit's rounds, aggregation, logging, checkpoints.
- :class:`FederationPlan`: the schemes ``central``, ``separate``, ``fedavg``.

The Flower backend lives beside this package, in :mod:`frl.flower`.
"""

from frl.federation.client import ClientSpec, LocalUpdate, VehicleClient
from frl.federation.client_pool import ClientPool, ProcessClientPool
from frl.federation.coordinator import Coordinator
from frl.federation.fedavg import TARGET_MODES, WEIGHTINGS, fedavg, state_nbytes
from frl.federation.plan import (
    FEDERATION_BACKENDS,
    SCHEMES,
    FederationPlan,
    client_seeds,
    evaluation_seeds,
)
from frl.federation.workers import ClientFailure, WorkerPool, threads_per_worker

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
