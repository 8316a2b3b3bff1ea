"""The roadside unit's aggregation under ``federation.backend=flower``: Flower's own
strategy classes (``flwr.serverapp.strategy``) behind the coordinator's interface.

frl's coordinator draws the vehicles and carries the messages; each round's uploads go
to the strategy's ``configure_train`` / ``aggregate_train`` as Flower replies would, and
its result is the next global model. The maths is Flower's, but for the strategies whose
server step is the weighted mean alone (:data:`FRL_MEAN_STRATEGIES`, FedAvg among them):
Flower sums the uploads in float32, frl in float64, and the last bits that differ after
one round grow over a run into another driver. Those are averaged by frl's
:func:`~frl.federation.fedavg`, so that one seed trains one run on every backend. The
others keep Flower's arithmetic, which the processes backend matches to rounding
(tests/test_federation_strategies.py). The strategy's own state (FedAvgM's momentum,
FedOpt's moments) is read out for checkpoints and put back on resume.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from flwr.app import Array, ArrayRecord, ConfigRecord, Message, MetricRecord, RecordDict
from flwr.serverapp import strategy as flower_strategies
from torch import Tensor

from frl.federation.averaging import fedavg
from frl.federation.strategies import StrategySpec

FLOWER_CLASSES: dict[str, str] = {
    "fedavg": "FedAvg",
    "fedprox": "FedProx",
    "fedavgm": "FedAvgM",
    "fedadam": "FedAdam",
    "fedyogi": "FedYogi",
    "fedadagrad": "FedAdagrad",
    "fedmedian": "FedMedian",
    "fedtrimmedavg": "FedTrimmedAvg",
}
FRL_MEAN_STRATEGIES: tuple[str, ...] = ("fedavg", "fedprox")
"""Strategies whose server step is the weighted mean (FedProx's term acts in the
vehicles): frl's :func:`~frl.federation.fedavg` computes it, bit for bit the in-process
backend's mean."""
_STATE_ATTRIBUTES = ("momentum_vector", "m_t", "v_t")
"""Where Flower's strategies keep what they carry from round to round."""


class _Nodes:
    """A stand-in grid for ``configure_train``: the round's vehicles are already drawn."""

    def __init__(self, count: int) -> None:
        self.count = count

    def get_node_ids(self) -> list[int]:
        return list(range(1, self.count + 1))


class FlowerServerStrategy:
    """A Flower strategy driven by frl's coordinator (``aggregate``, ``state_dict``)."""

    def __init__(self, spec: StrategySpec) -> None:
        self.spec = spec
        cls = getattr(flower_strategies, FLOWER_CLASSES[spec.name])
        self.flower = cls(
            min_train_nodes=1, min_evaluate_nodes=0, min_available_nodes=1,
            fraction_evaluate=0.0, **spec.params,
        )  # fmt: skip
        self._keys: list[str] = []

    def aggregate(
        self,
        uploads: Sequence[Mapping[str, Tensor]],
        weights: Sequence[float] | None,
        current: Mapping[str, Tensor] | None,
        server_round: int,
    ) -> dict[str, Tensor]:
        """The next global model, by the Flower strategy's ``aggregate_train`` (by frl's
        mean for :data:`FRL_MEAN_STRATEGIES`)."""
        if self.spec.name in FRL_MEAN_STRATEGIES:
            return fedavg(uploads, weights)
        dtypes = {key: value.dtype for key, value in uploads[0].items()}
        self._keys = list(dtypes)
        if current is not None:
            # Tells the strategy the global model this round started from.
            self.flower.configure_train(
                server_round, _record(current), ConfigRecord(), _Nodes(len(uploads))
            )
        replies = [
            Message(
                RecordDict(
                    {
                        "arrays": _record(upload),
                        "metrics": MetricRecord(
                            {"num-examples": float(1.0 if weights is None else weights[i])}
                        ),
                    }
                ),
                dst_node_id=i + 1,
                message_type="train",
            )
            for i, upload in enumerate(uploads)
        ]
        arrays, _ = self.flower.aggregate_train(server_round, replies)
        if arrays is None:
            raise RuntimeError(f"Flower's {type(self.flower).__name__} aggregated nothing")
        return {
            key: torch.from_numpy(np.array(arrays[key].numpy(), copy=True)).to(dtypes[key])
            for key in dtypes
        }

    def state_dict(self) -> dict[str, Tensor]:
        """The strategy's momentum or moments as flat tensors (``m_t/actor.0.weight``)."""
        flat: dict[str, Tensor] = {}
        for attribute in _STATE_ATTRIBUTES:
            value = getattr(self.flower, attribute, None)
            if value is None:
                continue
            items = (
                value.items() if isinstance(value, dict) else zip(self._keys, value, strict=True)
            )
            for key, array in items:
                flat[f"{attribute}/{key}"] = torch.from_numpy(np.array(array, copy=True))
        if flat:
            for index, key in enumerate(self._keys):
                flat[f"order/{key}"] = torch.tensor([index])
        return flat

    def load_state_dict(self, flat: Mapping[str, Tensor]) -> None:
        """Restore :meth:`state_dict` into the Flower strategy."""
        order = sorted(
            ((int(t.item()), name.split("/", 1)[1]) for name, t in flat.items()
             if name.startswith("order/"))
        )  # fmt: skip
        self._keys = [key for _, key in order]
        for attribute in _STATE_ATTRIBUTES:
            arrays = {
                name.split("/", 1)[1]: tensor.numpy()
                for name, tensor in flat.items()
                if name.startswith(f"{attribute}/")
            }
            if not arrays:
                continue
            if attribute == "momentum_vector":  # FedAvgM keeps a list in key order
                setattr(self.flower, attribute, [arrays[key] for key in self._keys])
            else:
                setattr(self.flower, attribute, arrays)


def _record(parameters: Mapping[str, Any]) -> ArrayRecord:
    return ArrayRecord(
        {key: Array(np.ascontiguousarray(_numpy(value))) for key, value in parameters.items()}
    )


def _numpy(value: Any) -> np.ndarray:
    return value.detach().cpu().numpy() if isinstance(value, Tensor) else np.asarray(value)
