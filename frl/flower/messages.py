"""The messages between the roadside unit (ServerApp) and a vehicle (ClientApp).

A message from the roadside unit holds a ``ConfigRecord`` ``"frl"`` (the request as
JSON text) and, when the global model goes down, an ``ArrayRecord`` ``"parameters"``.
A reply holds ``"frl"`` (the answer as JSON text: client name, episode records, step
counts), ``"parameters"`` (the model upload, if any), ``"series"`` (per-step rewards and
losses, float32) and a ``MetricRecord`` ``"metrics"`` with ``num-examples`` (the steps of
the round, Flower's FedAvg weight key). Arrays cross the wire as numpy ``.npy`` bytes
written with ``allow_pickle=False``; nothing is pickled.

Message types: ``train`` (local training), ``query.setup``, ``query.sync`` (global model
and/or checkpoint), ``query.load``, ``query.model``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np
from flwr.app import Array, ArrayRecord, ConfigRecord, RecordDict

from frl.federation.frames import Arrays

REQUEST = "frl"
PARAMETERS = "parameters"
SERIES = "series"
METRICS = "metrics"
QUERY_OPS: tuple[str, ...] = ("setup", "sync", "load", "model")

SOCKET_KEY = "frl-vehicle-socket"
AUTHKEY_KEY = "frl-vehicle-key"
PARTITION_KEY = "partition-id"
RUN_DIR_KEY = "run-dir"


def message_type(op: str) -> str:
    return "train" if op == "train" else f"query.{op}"


def arrays_to_record(arrays: Mapping[str, np.ndarray]) -> ArrayRecord:
    return ArrayRecord.from_array_dict(
        {key: Array(np.ascontiguousarray(value)) for key, value in arrays.items()}
    )


def record_to_arrays(record: ArrayRecord) -> Arrays:
    return {key: array.numpy() for key, array in record.items()}


def request_content(header: Mapping[str, Any], parameters: Arrays | None = None) -> RecordDict:
    content = RecordDict({REQUEST: ConfigRecord({"header": json.dumps(dict(header))})})
    if parameters:
        content[PARAMETERS] = arrays_to_record(parameters)
    return content


def read_header(content: RecordDict) -> dict[str, Any]:
    return json.loads(str(content.config_records[REQUEST]["header"]))
