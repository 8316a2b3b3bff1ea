"""The roadside unit as a Flower ServerApp: the frl rounds over a Flower Grid.

:func:`run_roadside_unit` is the ServerApp's work under either runtime: connect the
vehicles, then drive the same :class:`~frl.federation.coordinator.Coordinator` as the
process backend. :data:`server_app` is the deployment runtime's ServerApp, which trains
the run whose directory ``python -m frl.train`` prepared (the run config's ``run-dir``).
"""

from __future__ import annotations

import logging
import os
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from flwr.app import Context
from flwr.serverapp import Grid, ServerApp

from frl import run_directory as rundir
from frl.federation.assembly import client_specs, round_tester
from frl.federation.client import ClientSpec
from frl.federation.coordinator import run_logged
from frl.fileio import write_json_atomic
from frl.flower.grid_pool import FlowerClientPool
from frl.flower.messages import RUN_DIR_KEY
from frl.flower.strategies import FlowerServerStrategy
from frl.run_directory import RoundHook, RunState
from frl.train_config import TrainSettings, load_run_config, validate


def run_roadside_unit(
    grid: Any,
    settings: TrainSettings,
    specs: Sequence[ClientSpec],
    run_dir: Path,
    state: RunState,
    progress: bool = False,
    on_round_end: RoundHook | None = None,
) -> RunState:
    """The ServerApp's work: connect the vehicles, then the frl rounds over the grid."""
    flower = settings.flower
    pool = FlowerClientPool(
        grid,
        specs,
        run_dir,
        run_key=f"{run_dir.resolve()}#{uuid.uuid4().hex[:8]}",
        accept_failures=flower.accept_failures,
        min_clients=flower.min_clients,
        aggregates=settings.plan.aggregates,
        timeout_s=settings.worker_timeout_s,
        connect_timeout_s=flower.connect_timeout_s,
        dropped=state.dropped_clients,
    )
    pool.connect()
    return run_logged(
        settings.plan,
        pool,
        run_dir,
        state,
        FlowerServerStrategy(settings.strategy),
        settings.seed,
        progress,
        on_round_end,
        round_tester(settings),  # its workers run beside the roadside unit
    )


def serve_run_dir(grid: Any, run_dir: str) -> None:
    """The deployment ServerApp: train the run prepared in ``run_dir`` by ``frl.train``.

    Whatever stops it is written to the run's failure file for ``frl.train`` to raise.
    """
    directory = Path(run_dir)
    # frl's own messages only: Flower forwards this process's log records to the
    # SuperLink over HTTP, so a root handler at INFO would log its own requests.
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s: %(message)s"))
    frl_log = logging.getLogger("frl")
    frl_log.addHandler(handler)
    frl_log.setLevel(logging.DEBUG if os.environ.get("FRL_FLOWER_DEBUG") else logging.INFO)
    try:
        settings = validate(load_run_config(directory))
        state = rundir.read_state(directory) or RunState()
        run_roadside_unit(grid, settings, client_specs(settings), directory, state)
    except BaseException as error:
        write_json_atomic(
            directory / rundir.FLOWER_FAILURE_FILE,
            {
                "type": type(error).__name__,
                "client": getattr(error, "client", None),
                "message": str(error),
            },
        )
        raise


server_app = ServerApp()
"""The ServerApp of the deployment runtime: trains the run whose directory the run
config names (``run-dir``, written by ``python -m frl.train``)."""


@server_app.main()
def _deployment_main(grid: Grid, context: Context) -> None:
    serve_run_dir(grid, str(context.run_config[RUN_DIR_KEY]))
