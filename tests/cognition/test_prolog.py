"""The DIARC (Prolog) rules flag exactly what the clingo rules flag, run by SWI-Prolog over the same steps."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from tests.cognition.scenes import APPROACH, GOAL, VOCAB, arrays
from tests.cognition.test_rules import CASES, ON_OWN_CABINET

from vlaprobe.cognition import Cognition, CognitionConfig
from vlaprobe.cognition.prolog import prolog_violations
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols import Goal

needs_swipl = pytest.mark.skipif(shutil.which("swipl") is None, reason="SWI-Prolog (swipl) is not installed")


def both(
    object_atoms: tuple[str, ...],
    action_atoms: tuple[str, ...],
    goal: Goal,
    rows: list[tuple[np.ndarray, np.ndarray]],
) -> tuple[list[set], list[set]]:
    """Per step: (rule, atoms) flagged by clingo, and by SWI-Prolog given the same beliefs and history."""
    cog = Cognition(object_atoms, action_atoms, goal, CognitionConfig(debounce=1, recent_steps=3))
    asp, facts = [], []
    for obj, act in rows:
        step = cog.step(obj, act)
        asp.append({(v.rule, frozenset(v.atoms)) for v in step.violations})
        facts.append(cog.rules.facts())
    return asp, prolog_violations(facts, cog.rules.type_facts)


@needs_swipl
def test_prolog_equals_clingo_on_every_rule_case() -> None:
    rows = [arrays(s) for steps in CASES.values() for s in [APPROACH, *steps]] + [arrays(ON_OWN_CABINET)]
    asp, pl = both(VOCAB.object_atoms, VOCAB.action_atoms, GOAL, rows)
    assert sum(map(len, asp)) >= len(CASES)
    assert asp == pl


def noisy(obj: np.ndarray, act: np.ndarray, seed: int, rate: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """A drifting random walk over all atoms: each step flips a few atoms (probe-like noise)."""
    rng = np.random.default_rng(seed)
    rows, o, a = [], obj.copy(), act.copy()
    for _ in range(60):
        o ^= rng.random(o.shape) < rate
        a ^= rng.random(a.shape) < 4 * rate
        rows.append((o.copy(), a.copy()))
    return rows


@needs_swipl
def test_prolog_equals_clingo_on_noisy_sequences() -> None:
    rows = noisy(*arrays(APPROACH), seed=0, rate=0.01)
    asp, pl = both(VOCAB.object_atoms, VOCAB.action_atoms, GOAL, rows)
    flagged = {rule for step in asp for rule, _ in step}
    assert len(flagged) >= 8, flagged  # most rules get exercised
    assert asp == pl


def test_a_missing_prolog_is_a_one_line_error() -> None:
    with pytest.raises(VlaprobeError, match="not found; install SWI-Prolog"):
        prolog_violations([[]], [], swipl="no-such-swipl")
