"""Shared test set-up: a per-session scenario cache, and one torch thread on request."""

import os
import tempfile
from collections.abc import Iterator

import pytest
import torch


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


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """Small networks run fastest on one thread; it also keeps OpenMP threads from
    spinning against other processes on a shared CI machine."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
