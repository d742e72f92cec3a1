"""Quick mode of the benchmarks: ``VLAPROBE_BENCH_QUICK=1`` runs each at a token size (seconds, not minutes),
so that ``tests/test_benches.py`` can check that every bench still runs and prints its final JSON line. The
figures of a quick run mean nothing; benches take no arguments, hence the environment variable."""

from __future__ import annotations

import os
from typing import TypeVar

T = TypeVar("T")

QUICK = os.environ.get("VLAPROBE_BENCH_QUICK", "") not in ("", "0")


def size(full: T, quick: T) -> T:
    """``full`` normally, ``quick`` in quick mode."""
    return quick if QUICK else full
