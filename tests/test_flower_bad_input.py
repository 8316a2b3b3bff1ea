"""A Flower fleet set up wrong is refused in one line naming the option, before any work:
a SuperNode whose partition is not in the run, two SuperNodes with one partition, a
SuperLink address that answers nothing (for ``frl.train`` and for a vehicle's host).

Skipped (not failed) where Flower is not installed: ``pip install -e '.[flower]'``.
"""

from __future__ import annotations

import multiprocessing
from types import SimpleNamespace

import pytest
from test_cli_errors import assert_one_line_error, run_cli  # noqa: F401 (a fixture)
from train_helpers import tiny_spec

pytest.importorskip("flwr")

from frl.federation import ClientFailure
from frl.federation.reachability import unreachable_reason
from frl.federation.vehicle_host import VehicleError
from frl.flower import node
from frl.flower.client_app import node_partition
from frl.flower.grid_pool import FlowerClientPool
from frl.flower.messages import PARTITION_KEY, error_text, request_content

TASKS = ["left", "straight", "right"]


def _silent_address() -> str:
    """127.0.0.1 and a port nothing listens on."""
    return f"127.0.0.1:{node.free_port()}"


def _context(partition: int, num_partitions: int) -> SimpleNamespace:
    return SimpleNamespace(node_config={PARTITION_KEY: partition, "num-partitions": num_partitions})


def test_a_node_takes_its_own_partition_and_refuses_one_the_run_lacks():
    assert node_partition(_context(2, 3), num_vehicles=3) == 2
    with pytest.raises(VehicleError, match=r"^--partition-id 3 names no vehicle .* ids 0-2\)$"):
        node_partition(_context(3, 4), num_vehicles=3)
    with pytest.raises(VehicleError, match=r"^--num-partitions 4 does not match .* 3 vehicles$"):
        node_partition(_context(1, 4), num_vehicles=3)


@pytest.mark.parametrize(
    "reason",
    [
        "<class 'frl.federation.vehicle_host.VehicleError'>:<'--partition-id 3 names no vehicle'>",
        "<class 'flwr.clientapp.client_app.ClientAppException'>:<'\nException "
        "ClientAppException occurred. Message: <class 'frl.federation.vehicle_host."
        "VehicleError'>:<'--partition-id 3 names no vehicle'>'>",
        "\x1b[36mray::ClientAppActor.run()\x1b[39m (pid=1, ip=192.0.2.2)\n  File ...\n"
        "flwr.clientapp.client_app.ClientAppException: \nException ClientAppException "
        "occurred. Message: --partition-id 3 names no vehicle",
    ],
    ids=["deployment", "simulation", "simulation-traceback"],
)
def test_flowers_wrapping_of_a_client_error_is_taken_off(reason):
    assert error_text(reason) == "--partition-id 3 names no vehicle"
    assert error_text("plain words") == "plain words"


SUPERLINK_NODE_ID = 1
"""The node id Flower's SuperLink sends its own error replies from."""
NODE_UNAVAILABLE = "Error: Node Unavailable - The destination node failed to report a heartbeat"


class _Grid:
    """A Flower grid whose nodes answer ``query.setup`` as given (a partition or an error)
    and every other request with an empty reply; for a node in ``gone`` (its SuperNode
    killed) the SuperLink answers instead, as Flower does."""

    def __init__(self, answers: dict[int, int | str], gone: frozenset[int] = frozenset()) -> None:
        self.answers = answers
        self.gone = gone

    def get_node_ids(self) -> list[int]:
        return list(self.answers)

    def push_messages(self, messages):
        self.pushed = list(messages)
        for number, message in enumerate(self.pushed):
            message.metadata.__dict__["_message_id"] = f"request-{number}"  # as Flower does
        return [message.metadata.message_id for message in self.pushed]

    def pull_messages(self, message_ids):
        replies = []
        for message in self.pushed:
            if message.metadata.message_id not in message_ids:
                continue
            node_id = message.metadata.dst_node_id
            if message.metadata.message_type == "query.setup":
                answer = self.answers[node_id]
            else:
                answer = NODE_UNAVAILABLE if node_id in self.gone else {}
            error = isinstance(answer, str)
            replies.append(
                SimpleNamespace(
                    metadata=SimpleNamespace(
                        src_node_id=SUPERLINK_NODE_ID if node_id in self.gone else node_id,
                        reply_to_message_id=message.metadata.message_id,
                    ),
                    has_error=lambda error=error: error,
                    error=SimpleNamespace(reason=answer if error else ""),
                    content=request_content(
                        {} if error or isinstance(answer, dict) else {PARTITION_KEY: answer}
                    ),
                )
            )
        return replies[::-1]  # in no particular order


@pytest.fixture
def in_a_server_app(monkeypatch):
    """Messages take their run id from the task that builds them: a ServerApp's."""
    from flwr.supercore.task_identity import TaskIdentity

    for identity in ("_run_id", "_node_id", "_task_id"):
        monkeypatch.setattr(TaskIdentity, identity, 1)


def _pool(answers: dict[int, int | str], tmp_path, **options) -> FlowerClientPool:
    specs = [tiny_spec(i, task) for i, task in enumerate(TASKS)]
    grid = _Grid(answers, options.pop("gone", frozenset()))
    return FlowerClientPool(grid, specs, tmp_path, "run", connect_timeout_s=1, **options)


def test_a_supernode_gone_mid_run_is_named_by_its_vehicle(in_a_server_app, tmp_path):
    """The SuperLink answers for a SuperNode that missed its heartbeats, from its own id:
    the failure still names the vehicle the request was for."""
    answers = {21: 2, 22: 0, 23: 1}  # partitions in another order than the node ids
    pool = _pool(answers, tmp_path, gone=frozenset({23}), accept_failures=False)
    pool.connect()
    with pytest.raises(ClientFailure, match=r"client1_straight failed: Error: Node Unavailable"):
        pool.get_model(1)


def test_a_supernode_of_another_fleet_stops_the_run_before_any_round(in_a_server_app, tmp_path):
    refused = "<class 'VehicleError'>:<'--partition-id 3 names no vehicle of this run'>"
    pool = _pool({11: 0, 12: 1, 13: 2, 14: refused}, tmp_path)
    with pytest.raises(ClientFailure, match=r"SuperNode 14 refused the run: --partition-id 3"):
        pool.connect()


def test_two_supernodes_with_one_partition_stop_the_run_before_any_round(in_a_server_app, tmp_path):
    pool = _pool({11: 0, 12: 1, 13: 1}, tmp_path)
    with pytest.raises(
        ClientFailure, match=r"SuperNodes 12 and 13 were both started with --partition-id 1"
    ):
        pool.connect()


def test_nothing_listening_is_told_apart_from_something_listening():
    assert "refused" in unreachable_reason(_silent_address()).lower()
    assert unreachable_reason("127.0.0.1:http") == "'http' is not a port number"
    import socket

    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        assert unreachable_reason(f"127.0.0.1:{listener.getsockname()[1]}") is None


def test_frl_train_with_a_superlink_that_answers_nothing(run_cli, tmp_path):  # noqa: F811
    address = _silent_address()
    result = run_cli(
        "frl.train",
        "federation.backend=flower",
        "federation.flower.runtime=deployment",
        f"federation.flower.superlink={address}",
        f"run_dir={tmp_path / 'run'}",
        cwd=tmp_path,
    )
    assert_one_line_error(
        result,
        "frl.train: config error: ",
        f"federation.flower.superlink={address}: nothing answers there (",
    )
    assert not (tmp_path / "run").exists() and not (tmp_path / "outputs").exists()
    assert multiprocessing.active_children() == []


@pytest.mark.parametrize(
    "args, text",
    [
        (["--superlink", "SILENT", "--partition-id", "0"], "--superlink SILENT: nothing answers"),
        (["--superlink", "SILENT", "--partition-id", "3"], "--partition-id 3 is not in [0, "),
        (["--superlink", "SILENT", "--partition-id", "0", "--num-partitions", "0"],
         "--num-partitions must be at least 1"),
    ],
    ids=["silent-superlink", "partition-out-of-range", "no-partitions"],
)  # fmt: skip
def test_a_vehicle_host_set_up_wrong_starts_nothing(args, text, capsys, tmp_path):
    address = _silent_address()
    args = [a.replace("SILENT", address) for a in args]
    if "--num-partitions" not in args:
        args += ["--num-partitions", "3"]
    with pytest.raises(SystemExit) as stop:
        node.main([*args, "--state-dir", str(tmp_path / "state")])
    assert stop.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and text.replace("SILENT", address) in lines[0], lines
    assert multiprocessing.active_children() == [] and not (tmp_path / "state").exists()
