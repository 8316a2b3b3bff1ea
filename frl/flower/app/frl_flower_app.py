"""Flower app components: frl's roadside unit and vehicle apps, from the installed frl."""

from frl.flower.client_app import client_app
from frl.flower.server_app import server_app

__all__ = ["client_app", "server_app"]
