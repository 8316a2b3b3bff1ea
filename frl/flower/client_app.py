"""The vehicle as a Flower ClientApp: a stateless relay to its vehicle process.

The ClientApp holds no state: it relays every message (:mod:`frl.flower.messages`) to
its vehicle process (:mod:`frl.flower.vehicle`), found through the node config
(``frl-vehicle-socket``, ``frl-vehicle-key``) or, in simulation, through a mapping
given to :func:`make_client_app`.
"""

from __future__ import annotations

import json
import traceback
from collections.abc import Callable

from flwr.app import ConfigRecord, Context, Message, MetricRecord, RecordDict
from flwr.clientapp import ClientApp

from frl.federation.frames import Arrays, prefixed, unprefixed
from frl.flower.messages import (
    AUTHKEY_KEY,
    METRICS,
    NUM_PARTITIONS_KEY,
    PARAMETERS,
    PARTITION_KEY,
    QUERY_OPS,
    REQUEST,
    SERIES,
    SOCKET_KEY,
    arrays_to_record,
    read_header,
    record_to_arrays,
)
from frl.flower.vehicle import (
    PARAMETERS_PREFIX,
    SERIES_PREFIX,
    VehicleEndpoint,
    VehicleError,
    call_vehicle,
)

EndpointLookup = Callable[[Context], VehicleEndpoint]


def node_endpoint(context: Context) -> VehicleEndpoint:
    """The vehicle process named in the node config (deployment runtime)."""
    config = context.node_config
    if SOCKET_KEY not in config or AUTHKEY_KEY not in config:
        raise VehicleError(
            f"this SuperNode has no vehicle: its node config lacks {SOCKET_KEY} and "
            f"{AUTHKEY_KEY}; start it with `python -m frl.flower.node`"
        )
    return VehicleEndpoint(str(config[SOCKET_KEY]), str(config[AUTHKEY_KEY]))


def node_partition(context: Context, num_vehicles: int) -> int:
    """The run's client this node hosts: its ``partition-id``, checked against the run.

    Raises:
        VehicleError: the node was started for another fleet (``--partition-id`` or
            ``--num-partitions`` of ``python -m frl.flower.node`` do not fit the run).
    """
    partition = int(context.node_config[PARTITION_KEY])
    declared = int(context.node_config.get(NUM_PARTITIONS_KEY, num_vehicles))
    if not 0 <= partition < num_vehicles:
        raise VehicleError(
            f"--partition-id {partition} names no vehicle of this run: it has {num_vehicles} "
            f"(partition ids 0-{num_vehicles - 1})"
        )
    if declared != num_vehicles:
        raise VehicleError(
            f"--num-partitions {declared} does not match this run's {num_vehicles} vehicles"
        )
    return partition


def relay(message: Message, context: Context, endpoint_for: EndpointLookup) -> Message:
    """Forward ``message`` to the vehicle process and wrap its answer as the reply."""
    header = read_header(message.content)
    if header["op"] == "setup":  # every node gets every spec; it takes its own
        specs = header.pop("specs")
        header["spec"] = specs[node_partition(context, len(specs))]
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
