"""Probes for the live tests: a small store collected from the fake simulator and model, and probes on it."""

from __future__ import annotations

from pathlib import Path

import pytest
from tests.collection.fakes import fake_probed_run


@pytest.fixture(scope="session")
def fake_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run folder with ``activations/`` (fake episodes) and ``probes/`` trained on them."""
    root = tmp_path_factory.mktemp("run")
    fake_probed_run(root, shuffled_control=False)
    return root
