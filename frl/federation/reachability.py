"""Is anything listening at ``host:port``? Asked before a run depends on a remote service."""

from __future__ import annotations

import socket


def unreachable_reason(address: str, timeout_s: float = 5.0) -> str | None:
    """Why nothing answers a TCP connection to ``address`` (``host:port``) within
    ``timeout_s``, or None when something accepts it."""
    host, _, port_text = address.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        return f"{port_text!r} is not a port number"
    if not 0 < port < 65536:
        return f"port {port} is out of range"
    try:
        with socket.create_connection((host.strip("[]"), port), timeout=timeout_s):
            return None
    except socket.gaierror as error:
        return f"the host {host!r} is unknown ({error.strerror})"
    except TimeoutError:
        return f"no answer within {timeout_s:g} s"
    except OSError as error:
        return error.strerror or str(error)
