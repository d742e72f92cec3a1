"""Users' rules are checked before use and bounded while used: grounding and solving budgets, UTF-8."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from tests.cognition.scenes import GOAL, VOCAB

from vlaprobe.cognition import RuleEngine
from vlaprobe.cognition.budget import choice_rules, growing_rules
from vlaprobe.configs.monitor import RuleBudget
from vlaprobe.errors import VlaprobeError

ATOMS = VOCAB.object_atoms + VOCAB.action_atoms
UNBOUNDED = "n(0). n(X+1) :- n(X).\n"
PIGEONS = (  # pigeonhole, 14 into 13: grounds at once, a search no solver finishes in seconds
    "pigeon(1..14). hole(1..13).\n"
    "1 { in(P,H) : hole(H) } 1 :- pigeon(P).\n"
    "clash :- in(P,H), in(Q,H), P < Q, not clash.\n"
)


def write(tmp_path: Path, text: str | bytes, name: str = "mine.lp") -> Path:
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def step0(engine: RuleEngine) -> list:
    none = np.zeros(0, dtype=np.int64)
    return engine.evaluate(0, np.zeros(len(ATOMS), dtype=bool), none, none)


@pytest.mark.serial
def test_an_unbounded_rule_stops_at_the_grounding_budget_naming_the_rule(tmp_path: Path) -> None:
    path = write(tmp_path, "% counting\n" + UNBOUNDED)
    start = time.monotonic()
    with pytest.raises(VlaprobeError) as err:
        RuleEngine(ATOMS, GOAL, rules=(path,), budget=RuleBudget(ground_seconds=1))
    message = str(err.value)
    assert time.monotonic() - start < 30
    assert "did not finish within 1 s" in message and f"{path}:2:" in message and "n(X)" in message
    assert "\n" not in message


@pytest.mark.serial
def test_the_memory_budget_stops_grounding_too(tmp_path: Path) -> None:
    path = write(tmp_path, UNBOUNDED)
    with pytest.raises(VlaprobeError, match=r"ran out of its 120 MB of memory: rule .*n\(X\)"):
        RuleEngine(ATOMS, GOAL, rules=(path,), budget=RuleBudget(ground_seconds=60, ground_memory_mb=120))
    with pytest.raises(VlaprobeError, match="could not start within 5 MB"):
        RuleEngine(ATOMS, GOAL, rules=(path,), budget=RuleBudget(ground_memory_mb=5))


def test_a_finite_program_over_the_atom_budget_is_refused(tmp_path: Path) -> None:
    path = write(tmp_path, "big(X,Y,Z) :- object(X), object(Y), object(Z).\n")
    with pytest.raises(VlaprobeError, match="atoms, over the budget of 100"):
        RuleEngine(ATOMS, GOAL, rules=(path,), budget=RuleBudget(ground_atoms=100))
    RuleEngine(ATOMS, GOAL, rules=(path,))  # within the default budget


def test_a_hard_search_stops_at_the_solving_budget_naming_the_choice(tmp_path: Path) -> None:
    path = write(tmp_path, PIGEONS)
    engine = RuleEngine(ATOMS, GOAL, rules=(path,), budget=RuleBudget(solve_seconds=0.5))
    start = time.monotonic()
    with pytest.raises(VlaprobeError) as err:
        step0(engine)
    assert time.monotonic() - start < 10
    assert "took longer than 0.5 s" in str(err.value) and f"{path}:2:" in str(err.value)


def test_a_rules_file_not_utf8_is_one_line(tmp_path: Path) -> None:
    path = write(tmp_path, b"violation(r, X) :- on(X,Y). % caf\xe9\n")
    with pytest.raises(VlaprobeError, match="is not UTF-8 text"):
        RuleEngine(ATOMS, GOAL, rules=(path,))


def test_a_folder_as_rules_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(VlaprobeError, match="rules file is a folder"):
        RuleEngine(ATOMS, GOAL, rules=(tmp_path,))


@pytest.mark.parametrize("field", ["ground_seconds", "solve_seconds", "ground_atoms", "ground_memory_mb"])
def test_a_budget_that_bounds_nothing_is_refused(field: str) -> None:
    with pytest.raises(VlaprobeError, match=f"rule budget {field} must be"):
        RuleEngine(ATOMS, GOAL, budget=RuleBudget(**{field: 0}))


def test_good_user_rules_still_run_within_the_budget(tmp_path: Path) -> None:
    path = write(tmp_path, 'message(stove_on, "on").\nviolation(stove_on, turned_on(K)) :- turned_on(K).\n')
    engine = RuleEngine(ATOMS, GOAL, rules=(path,), shipped=False)
    assert step0(engine) == []


def test_the_blamed_rules_are_the_growing_and_the_choosing_ones(tmp_path: Path) -> None:
    path = write(tmp_path, "p(1..3).\nq(f(X)) :- p(X).\nq(f(X)) :- q(X).\nr(X+1) :- p(X).\n" + PIGEONS)
    assert [r.split(": ")[0] for r in growing_rules([path])] == [f"{path}:3"]
    assert [r.split(": ")[0] for r in choice_rules([path])] == [f"{path}:6"]
