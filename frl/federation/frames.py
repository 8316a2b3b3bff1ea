"""Frames: every message to and from a vehicle process, without pickle.

A frame is a length-prefixed JSON header followed by an ``.npz`` archive of arrays,
read back with ``allow_pickle=False``. Both backends speak it to their vehicle
processes (:mod:`frl.federation.vehicle_host` answers). Only numpy and the standard
library are imported here: a Flower ClientApp, started afresh for every message, must
start fast.
"""

from __future__ import annotations

import io
import json
import struct
from collections.abc import Mapping
from typing import Any

import numpy as np

Arrays = dict[str, np.ndarray]

_HEADER = struct.Struct("!I")


def prefixed(arrays: Mapping[str, np.ndarray], prefix: str) -> Arrays:
    return {prefix + key: value for key, value in arrays.items()}


def unprefixed(arrays: Mapping[str, np.ndarray], prefix: str) -> Arrays:
    return {key[len(prefix) :]: value for key, value in arrays.items() if key.startswith(prefix)}


def encode_frame(
    header: Mapping[str, Any], arrays: Mapping[str, np.ndarray] | None = None
) -> bytes:
    """One message of the local channel: length-prefixed JSON, then an ``.npz`` archive."""
    text = json.dumps(dict(header)).encode()
    buffer = io.BytesIO()
    if arrays:
        plain = {key: np.asarray(value) for key, value in arrays.items()}
        for key, value in plain.items():
            if value.dtype.hasobject:  # would be pickled
                raise ValueError(f"{key!r} is an object array; frames carry numbers only")
        np.savez(buffer, **plain)
    return _HEADER.pack(len(text)) + text + buffer.getvalue()


def frame_header(frame: bytes) -> dict[str, Any]:
    """A frame's JSON header alone, its arrays left unread."""
    (length,) = _HEADER.unpack_from(frame)
    return json.loads(frame[_HEADER.size : _HEADER.size + length])


def decode_frame(frame: bytes) -> tuple[dict[str, Any], Arrays]:
    """Inverse of :func:`encode_frame`; arrays are loaded with ``allow_pickle=False``."""
    (length,) = _HEADER.unpack_from(frame)
    start = _HEADER.size
    header = frame_header(frame)
    if len(frame) == start + length:
        return header, {}
    # Read the archive in place (zipfile finds it after the header) rather than from a
    # copy of the frame's tail: a model upload is megabytes, received once per vehicle.
    stream = io.BytesIO(frame)
    stream.seek(start + length)
    with np.load(stream, allow_pickle=False) as archive:
        return header, {key: archive[key] for key in archive.files}
