"""The vehicle as a Flower ClientApp, and the roadside unit as a Flower ServerApp.

A message from the roadside unit holds a ``ConfigRecord`` ``"frl"`` (the request as
JSON text) and, when the global model goes down, an ``ArrayRecord`` ``"parameters"``.
A reply holds ``"frl"`` (the answer as JSON text: client name, episode records, step
counts), ``"parameters"`` (the model upload, if any), ``"series"`` (per-step rewards and
losses, float32) and a ``MetricRecord`` ``"metrics"`` with ``num-examples`` (the steps of
the round, Flower's FedAvg weight key). Arrays cross the wire as numpy ``.npy`` bytes
written with ``allow_pickle=False``; nothing is pickled.

Message types: ``train`` (local training), ``query.setup``, ``query.sync`` (global model
and/or checkpoint), ``query.load``, ``query.model``.

The ClientApp holds no state: it relays every message to its vehicle process
(:mod:`frl.flower.vehicle`), found through the node config
(``frl-vehicle-socket``, ``frl-vehicle-key``) or, in simulation, through a mapping
given to :func:`make_client_app`.
"""

from __future__ import annotations

import json
import traceback
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from flwr.app import Array, ArrayRecord, ConfigRecord, Context, Message, MetricRecord, RecordDict
from flwr.clientapp import ClientApp
from flwr.serverapp import Grid, ServerApp

from frl.flower.frames import Arrays, prefixed, unprefixed
from frl.flower.vehicle import (
    PARAMETERS_PREFIX,
    SERIES_PREFIX,
    VehicleEndpoint,
    VehicleError,
    call_vehicle,
)

REQUEST = "frl"
PARAMETERS = "parameters"
SERIES = "series"
METRICS = "metrics"
QUERY_OPS: tuple[str, ...] = ("setup", "sync", "load", "model")

SOCKET_KEY = "frl-vehicle-socket"
AUTHKEY_KEY = "frl-vehicle-key"
PARTITION_KEY = "partition-id"
RUN_DIR_KEY = "run-dir"

EndpointLookup = Callable[[Context], VehicleEndpoint]


def message_type(op: str) -> str:
    return "train" if op == "train" else f"query.{op}"


# ------------------------------------------------------------------ records
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


# ------------------------------------------------------------------ the vehicle
def node_endpoint(context: Context) -> VehicleEndpoint:
    """The vehicle process named in the node config (deployment runtime)."""
    config = context.node_config
    if SOCKET_KEY not in config or AUTHKEY_KEY not in config:
        raise VehicleError(
            f"this SuperNode has no vehicle: its node config lacks {SOCKET_KEY} and "
            f"{AUTHKEY_KEY}; start it with `python -m frl.flower.node`"
        )
    return VehicleEndpoint(str(config[SOCKET_KEY]), str(config[AUTHKEY_KEY]))


def relay(message: Message, context: Context, endpoint_for: EndpointLookup) -> Message:
    """Forward ``message`` to the vehicle process and wrap its answer as the reply."""
    header = read_header(message.content)
    if header["op"] == "setup":  # every node gets every spec; it takes its own
        partition = int(context.node_config[PARTITION_KEY])
        specs = header.pop("specs")
        if not 0 <= partition < len(specs):
            raise VehicleError(f"partition-id {partition} names no vehicle of this run")
        header["spec"] = specs[partition]
    arrays: Arrays = {}
    if PARAMETERS in message.content.array_records:
        arrays = prefixed(record_to_arrays(message.content[PARAMETERS]), PARAMETERS_PREFIX)
    reply, out = call_vehicle(endpoint_for(context), header, arrays)
    if header["op"] == "setup":
        reply[PARTITION_KEY] = int(context.node_config[PARTITION_KEY])
    content = RecordDict({REQUEST: ConfigRecord({"header": json.dumps(reply)})})
    parameters = unprefixed(out, PARAMETERS_PREFIX)
    if parameters:
        content[PARAMETERS] = arrays_to_record(parameters)
    series = unprefixed(out, SERIES_PREFIX)
    if series:
        content[SERIES] = arrays_to_record(series)
    summary = reply.get("summary")
    if summary is not None:
        content[METRICS] = MetricRecord(
            {
                "num-examples": int(summary["num_steps"]),
                "episodes": len(summary["episodes"]),
                "cpu-time-s": float(summary["cpu_time_s"]),
            }
        )
    return Message(content, reply_to=message)


def make_client_app(endpoint_for: EndpointLookup = node_endpoint) -> ClientApp:
    """A ClientApp relaying every frl message to the vehicle ``endpoint_for(context)``."""
    app = ClientApp()

    def handler(message: Message, context: Context) -> Message:
        try:
            return relay(message, context, endpoint_for)
        except VehicleError:
            raise
        except Exception as error:  # give the roadside unit the whole story
            raise VehicleError(f"{error!r}\n{traceback.format_exc()}") from error

    app.train()(handler)
    for op in QUERY_OPS:
        app.query(op)(handler)
    return app


client_app = make_client_app()
"""The ClientApp of a SuperNode started by ``python -m frl.flower.node``."""


# ------------------------------------------------------------------ the roadside unit
server_app = ServerApp()
"""The ServerApp of the deployment runtime: trains the run whose directory the run
config names (``run-dir``, written by ``python -m frl.train``)."""


@server_app.main()
def _deployment_main(grid: Grid, context: Context) -> None:
    from frl.flower.runtime import serve_run_dir

    serve_run_dir(grid, str(context.run_config[RUN_DIR_KEY]))
