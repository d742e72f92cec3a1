"""Shared test setup: LIBERO assets, the shared reference folder, one BLAS/torch thread per xdist worker."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("VLAPROBE_SHARED", REPO.parent / "shared"))

# `make test` runs two pytest-xdist workers on the parallel pass: each on one thread (two workers with a thread
# per core each oversubscribe the cores several times over). Set before torch is imported by any test.
if os.environ.get("PYTEST_XDIST_WORKER"):
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = "1"
    import torch

    torch.set_num_threads(1)

# Offline machines: use the shared assets folder beside the checkout when the user named none.
if "VLAPROBE_LIBERO_ASSETS" not in os.environ and (SHARED / "libero_assets").is_dir():
    os.environ["VLAPROBE_LIBERO_ASSETS"] = str(SHARED / "libero_assets")


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The ``shared/`` folder beside the checkout (reference vectors, assets); skips when absent."""
    if not SHARED.is_dir():
        pytest.skip(f"shared folder not found at {SHARED}; set VLAPROBE_SHARED")
    return SHARED


def _rank(item: pytest.Item) -> int:
    """0 for the slowest files (marked ``heavy``), 1 for the other simulator files, 2 for the rest."""
    if item.get_closest_marker("heavy"):
        return 0
    return 1 if item.get_closest_marker("libero") else 2


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Start the slowest test files first: the two-worker pass hands out files in collection order, so a
    minutes-long file collected last would run alone at the end while the other worker idles."""
    rank: dict[str, int] = {}
    for item in items:
        path = item.nodeid.split("::")[0]
        rank[path] = min(rank.get(path, 2), _rank(item))
    items.sort(key=lambda item: rank[item.nodeid.split("::")[0]])  # stable: the order within a rank stays
