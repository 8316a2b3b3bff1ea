"""Flower app components: frl's roadside unit and vehicle apps, from the installed frl.

Each is imported only when Flower asks for it. A SuperNode starts a ClientApp process
for every message, and the vehicle's relay needs neither torch nor the roadside unit:
importing both cost each of those processes about 3 s of CPU, the ClientApp alone 1 s.
"""

from typing import Any

__all__ = ["client_app", "server_app"]  # noqa: F822 (module __getattr__ below)


def __getattr__(name: str) -> Any:
    if name == "client_app":
        from frl.flower.client_app import client_app

        return client_app
    if name == "server_app":
        from frl.flower.server_app import server_app

        return server_app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
