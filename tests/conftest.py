"""Shared test set-up: generated scenarios go to a per-session cache directory."""

import os
import tempfile

import pytest


@pytest.fixture(scope="session", autouse=True)
def _scenario_cache():
    """Keep the user's cache untouched; generate scenarios once per test session."""
    previous = os.environ.get("FRL_CACHE_DIR")
    with tempfile.TemporaryDirectory(prefix="frl-test-cache-") as directory:
        os.environ["FRL_CACHE_DIR"] = directory
        yield directory
    if previous is None:
        os.environ.pop("FRL_CACHE_DIR", None)
    else:
        os.environ["FRL_CACHE_DIR"] = previous
