"""What a check finds (:class:`Check`), and the doctor's output: one line per check, or one JSON object."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject

Status = Literal["ok", "warn", "fail", "skip"]
"""ok: there and working; warn: an optional piece is missing, or a caveat (the run still works); fail: a run
of these settings cannot work; skip: not checked (the line says why)."""

SYMBOLS: dict[Status, str] = {"ok": "✓", "warn": "!", "fail": "✗", "skip": "-"}

SETUP_FIX = "rerun `make setup` (or `bash scripts/setup.sh`)"
"""The fix of a broken installation."""

FORMAT = "vlaprobe-doctor"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class Check:
    """One check's result."""

    name: str
    """Stable id, e.g. "torch", "renderer.osmesa", "assets.libero_spatial" (scripts key on it)."""
    status: Status
    summary: str
    """What was found, one line."""
    fix: str = ""
    """What to do about a failure or warning ("" when there is nothing to do)."""
    seconds: float = 0.0
    """How long the check took."""
    figures: JsonObject = field(default_factory=dict)
    """What it measured (versions, timings, sizes), for scripts."""


def failure(name: str, exc: Exception) -> Check:
    """A failed check from what a check raised: a :class:`VlaprobeError`'s "problem; fix", else the exception."""
    if isinstance(exc, VlaprobeError):
        message, _, fix = str(exc).partition("; ")
        return Check(name, "fail", message, fix)
    return Check(name, "fail", f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}", SETUP_FIX)


def timed(name: str, check: Callable[[], Check]) -> Check:
    """``check()`` with its duration; what it raises becomes a failed check (:func:`failure`)."""
    start = time.perf_counter()
    try:
        result = check()
    except Exception as exc:  # the doctor reports what breaks and goes on with the other checks
        result = failure(name, exc)
    seconds = round(time.perf_counter() - start, 3)
    return Check(result.name, result.status, result.summary, result.fix, seconds, result.figures)


def timed_all(name: str, checks: Callable[[], list[Check]]) -> list[Check]:
    """Checks that come as a list; one failed check named ``name`` when the list cannot be made."""
    try:
        return checks()
    except Exception as exc:
        return [failure(name, exc)]


def ready(checks: Sequence[Check]) -> bool:
    """Whether a run of the checked settings can go ahead: no check failed."""
    return all(c.status != "fail" for c in checks)


def line(check: Check) -> str:
    """``✓ name  summary — fix: ...  (1.2 s)``."""
    fix = f" — fix: {check.fix}" if check.fix else ""
    return f"{SYMBOLS[check.status]} {check.name:<24} {check.summary}{fix}  ({check.seconds:.1f} s)"


def closing_line(checks: Sequence[Check], seconds: float) -> str:
    failed = sum(c.status == "fail" for c in checks)
    warned = sum(c.status == "warn" for c in checks)
    verdict = (
        "ready for `vlaprobe run` with these settings"
        if not failed
        else f"not ready: fix the {failed} failed check{'s' * (failed != 1)} first"
    )
    return f"doctor: {len(checks)} checks, {failed} failed, {warned} warnings in {seconds:.1f} s; {verdict}"


def to_json(checks: Sequence[Check], seconds: float) -> JsonObject:
    """The ``--json`` object: ``{"format", "format_version", "ready", "seconds", "checks": [...]}``."""
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "ready": ready(checks),
        "seconds": round(seconds, 3),
        "checks": [
            {
                "name": c.name,
                "status": c.status,
                "summary": c.summary,
                "fix": c.fix,
                "seconds": c.seconds,
                "figures": c.figures,
            }
            for c in checks
        ],
    }
