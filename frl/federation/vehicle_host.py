"""The vehicle's side of the wire: a :class:`VehicleHost` answers request frames.

Both backends talk to a vehicle process in the same requests (:class:`VehicleHost`)
and the same frames (:mod:`frl.federation.frames`): ``federation.backend=processes``
over each worker's pipe (:class:`frl.federation.ProcessClientPool`), ``flower`` over
the vehicle process's Unix socket that its ClientApp relays to
(:mod:`frl.flower.vehicle`).

Light imports only: a Flower ClientApp imports this module for every message. The
vehicle's own work (torch, SUMO) is imported when a vehicle is set up.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from frl.federation.frames import Arrays, decode_frame, encode_frame, prefixed, unprefixed

SERIES_PREFIX = "series/"
PARAMETERS_PREFIX = "parameters/"
MODEL_FILE_KEY = "model_file"
"""The array (uint8) a ``model_file`` reply carries the file's bytes in."""


class VehicleError(RuntimeError):
    """The vehicle process failed a request, or could not be reached."""


class VehicleHost:
    """What the vehicle process holds across rounds, and the requests it answers.

    Requests (``header["op"]``): ``ping``; ``setup`` builds the vehicle of a run
    (idempotent); ``train`` runs local training; ``sync`` loads the global model and/or
    writes a checkpoint; ``load`` restores one and says whether it held the vehicle's
    drive; ``model`` returns the networks (online and target); ``save_model`` writes the
    model file under ``state_dir``, and ``model_file`` returns that file's bytes (Flower:
    the roadside unit writes it). Paths are relative to ``state_dir`` and must stay
    inside it.
    """

    def __init__(self, state_dir: str | os.PathLike[str]) -> None:
        self.state_dir = Path(state_dir)
        self.client: Any = None
        self.run_key: str | None = None
        self.spec_json: str | None = None

    def serve(self, frame: bytes, progress: Callable[..., None] | None = None) -> bytes:
        """Answer one request frame with a reply frame (the worker-pipe carrier)."""
        header, arrays = decode_frame(frame)
        reply, out = self.handle(header, arrays, progress)
        return encode_frame({"ok": True, **reply}, out)

    def handle(
        self,
        header: Mapping[str, Any],
        arrays: Arrays,
        progress: Callable[..., None] | None = None,
    ) -> tuple[dict[str, Any], Arrays]:
        """One request: its reply header and arrays. ``progress`` sees local training."""
        from frl.federation.codec import arrays_to_tensors, tensors_to_arrays

        op = header["op"]
        if op == "ping":
            return {"run_key": self.run_key}, {}
        if op == "setup":
            return self._setup(str(header["run_key"]), str(header["spec"])), {}
        client = self._client_for(header)
        if op == "train":
            update = client.train(*_training_options(header), progress=progress)
            return training_reply(update)
        if op == "sync":
            if header.get("parameters"):
                parameters = arrays_to_tensors(unprefixed(arrays, PARAMETERS_PREFIX), copy=False)
                client.set_parameters(parameters, sync_targets=bool(header["sync_targets"]))
            if header.get("checkpoint"):
                self._save(str(header["checkpoint"]))
            return {}, {}
        if op == "load":
            return {"drive_restored": client.load(self._path(str(header["checkpoint"])))}, {}
        if op == "model":
            return {}, prefixed(tensors_to_arrays(client.get_parameters(True)), PARAMETERS_PREFIX)
        if op == "save_model":
            client.save_model(self._path(str(header["path"])))
            return {}, {}
        if op == "model_file":  # save_model's file, for a roadside unit on another host
            data = np.frombuffer(client.model_file(), np.uint8)
            return {}, prefixed({MODEL_FILE_KEY: data}, PARAMETERS_PREFIX)
        raise VehicleError(f"unknown request {op!r}")

    def training_round(
        self, header: Mapping[str, Any], progress: Callable[..., None] | None = None
    ) -> Any:
        """A ``train`` request as the vehicle's round a step at a time
        (:meth:`frl.federation.client.VehicleClient.training_round`), for a process that
        drives its vehicles' rounds in lockstep; :func:`training_reply` answers it."""
        if header.get("op") != "train":
            raise VehicleError(f"expected a train request, got {header.get('op')!r}")
        client = self._client_for(header)
        return client.training_round(*_training_options(header), progress=progress)

    def _client_for(self, header: Mapping[str, Any]) -> Any:
        """The vehicle a request is for, which must have been set up for its run."""
        if self.client is None or header.get("run_key") != self.run_key:
            raise VehicleError(
                f"{header.get('op')!r} for run {header.get('run_key')!r}, which was not set up"
            )
        return self.client

    def _setup(self, run_key: str, spec_json: str) -> dict[str, Any]:
        if self.client is not None and (run_key, spec_json) == (self.run_key, self.spec_json):
            return {"client": self.client.name, "built": False}  # a repeated setup
        self.close()
        from frl.federation.client import VehicleClient
        from frl.federation.codec import spec_from_json

        self.client = VehicleClient(spec_from_json(spec_json))
        self.run_key, self.spec_json = run_key, spec_json
        return {"client": self.client.name, "built": True}

    def _path(self, relative: str) -> Path:
        path = (self.state_dir / relative).resolve()
        if self.state_dir.resolve() not in path.parents:
            raise VehicleError(f"{relative!r} lies outside the vehicle's state_dir")
        return path

    def _save(self, relative: str) -> None:
        directory = self._path(relative)
        self.client.save(directory)
        # Keep this round and the one before (the last committed one); drop older files
        # of this vehicle. Where state_dir is the run directory, the roadside unit prunes too.
        name = self.client.name
        rounds = sorted(p for p in directory.parent.glob("round_*") if p.name < directory.name)
        for old in rounds[:-1]:
            for stale in old.glob(f"{name}.*"):  # model, counters and drive
                stale.unlink(missing_ok=True)
            with contextlib.suppress(OSError):
                old.rmdir()

    def close(self) -> None:
        if self.client is not None:
            with contextlib.suppress(Exception):
                self.client.close()
        self.client = None
        self.run_key = self.spec_json = None


def _training_options(header: Mapping[str, Any]) -> tuple[int, bool, bool]:
    """A train request's steps, upload and whether the upload has the target networks."""
    return int(header["num_steps"]), bool(header["upload"]), bool(header["include_targets"])


def training_reply(update: Any) -> tuple[dict[str, Any], Arrays]:
    """The reply to a train request: the round's summary, its series and its upload."""
    from frl.federation.codec import update_to_parts

    parameters, series, summary = update_to_parts(update)
    out = prefixed(series, SERIES_PREFIX)
    if parameters is not None:
        out.update(prefixed(parameters, PARAMETERS_PREFIX))
    return {"summary": summary, "upload": parameters is not None}, out
