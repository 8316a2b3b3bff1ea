"""Flower app components: frl's roadside unit and vehicle apps, from the installed frl."""

from frl.flower.apps import client_app, server_app

__all__ = ["client_app", "server_app"]
