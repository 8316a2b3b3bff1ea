"""The messages between the roadside unit (ServerApp) and a vehicle (ClientApp).

A message from the roadside unit holds a ``ConfigRecord`` ``"frl"`` (the request as
JSON text) and, when the global model goes down, an ``ArrayRecord`` ``"parameters"``.
A reply holds ``"frl"`` (the answer as JSON text: client name, episode records, step
counts), ``"parameters"`` (the model upload, if any), ``"series"`` (per-step rewards and
losses, float32) and a ``MetricRecord`` ``"metrics"`` with ``num-examples`` (the steps of
the round, Flower's FedAvg weight key). Arrays cross the wire as numpy ``.npy`` bytes
written with ``allow_pickle=False``; nothing is pickled.

Message types: ``train`` (local training), ``query.setup``, ``query.sync`` (global model
and/or checkpoint), ``query.load``, ``query.model`` (the networks), ``query.model_file``
(the final model file).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from typing import Any

import numpy as np
from flwr.app import Array, ArrayRecord, ConfigRecord, RecordDict

from frl.federation.frames import Arrays

REQUEST = "frl"
PARAMETERS = "parameters"
SERIES = "series"
METRICS = "metrics"
QUERY_OPS: tuple[str, ...] = ("setup", "sync", "load", "model", "model_file")

SOCKET_KEY = "frl-vehicle-socket"
AUTHKEY_KEY = "frl-vehicle-key"
PARTITION_KEY = "partition-id"
NUM_PARTITIONS_KEY = "num-partitions"
RUN_DIR_KEY = "run-dir"


_ANSI_CODE = re.compile(r"\x1b\[[0-9;]*m")
_FLOWER_MARKER = "occurred. Message:"


def error_text(reason: str) -> str:
    """What a ClientApp's exception said, without Flower's wrapping of it:
    ``<class 'X'>:<'message'>`` (deployment), or a Ray traceback ending in ``Exception
    ClientAppException occurred. Message: message`` (simulation)."""
    text = _unwrapped(_ANSI_CODE.sub("", reason).strip())
    if _FLOWER_MARKER in text:
        text = text.rsplit(_FLOWER_MARKER, 1)[1].strip()
    return _unwrapped(text)


def _unwrapped(text: str) -> str:
    if text.startswith("<class ") and ":<'" in text and text.endswith("'>"):
        return text.split(":<'", 1)[1][:-2].strip()
    return text


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
