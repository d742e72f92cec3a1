"""The belief store: debouncing, per-step differences, the interval history; unprobed atoms never flip."""

from __future__ import annotations

import numpy as np
import pytest
from tests.cognition.scenes import APPROACH, BOWL2, COOKIES, GOAL, VOCAB, arrays

from vlaprobe.cognition import BeliefStore, Cognition, CognitionConfig, Interval
from vlaprobe.configs.monitor import DEFAULT_DEBOUNCE
from vlaprobe.errors import VlaprobeError

FLICKER = f"left-of({BOWL2},{COOKIES})"  # alone it violates left_right_converse


def flicker_run(length: int, debounce: int = DEFAULT_DEBOUNCE) -> list:
    cog = Cognition(VOCAB.object_atoms, VOCAB.action_atoms, GOAL, CognitionConfig(debounce=debounce))
    steps = [set(APPROACH)] * 5 + [APPROACH | {FLICKER}] * length + [set(APPROACH)] * 8
    return [cog.step(*arrays(s)) for s in steps]


def test_default_debounce_suppresses_a_one_step_flicker_but_not_a_five_step_one() -> None:
    assert 1 < DEFAULT_DEBOUNCE <= 5
    short = flicker_run(1)
    assert not any(s.violations for s in short)
    assert not any(FLICKER in s.asserted or FLICKER in s.retracted for s in short)
    long = flicker_run(5)
    flagged = [s.t for s in long if s.violations]
    first = 5 + DEFAULT_DEBOUNCE - 1  # the flicker starts at step 5 and counts after DEFAULT_DEBOUNCE steps
    assert flagged[0] == first and long[first].violations[0].rule == "left_right_converse"
    assert FLICKER in long[first].asserted
    assert all(v.since == first for s in long for v in s.violations)
    # it also ends DEFAULT_DEBOUNCE steps after the input does
    assert flagged[-1] == 5 + 5 + DEFAULT_DEBOUNCE - 2


def test_without_debouncing_every_flicker_counts() -> None:
    steps = flicker_run(1, debounce=1)
    assert [s.t for s in steps if s.violations] == [5]
    assert steps[5].asserted == (FLICKER,) and steps[6].retracted == (FLICKER,)


def test_step_zero_asserts_every_true_atom_and_later_steps_only_changes() -> None:
    store = BeliefStore(["a(x)", "b(x)", "c(x)"], debounce=1)
    up, down = store.update(np.array([True, False, True]))
    assert up.tolist() == [0, 2] and down.size == 0
    up, down = store.update(np.array([True, True, False]))
    assert up.tolist() == [1] and down.tolist() == [2]


def test_history_answers_what_held_since_when_and_last_change() -> None:
    store = BeliefStore(["a(x)", "b(x)"], debounce=2)
    seq = [[1, 0], [1, 0], [0, 1], [0, 1], [0, 1], [1, 1], [1, 1], [1, 1]]
    for row in seq:
        store.update(np.array(row, dtype=bool))
    # a: true 0..2 (retraction counted at step 3), true again from 6; b: true from 3
    assert store.history("a(x)") == [Interval("a(x)", 0, 2), Interval("a(x)", 6, None)]
    assert store.since("b(x)") == 3 and store.last_change("a(x)") == 6
    assert store.holds("a(x)", 1) and not store.holds("a(x)", 4) and store.holds("a(x)")
    assert store.at(4) == {"b(x)"} and store.at(7) == {"a(x)", "b(x)"}


def test_unprobed_atoms_keep_their_first_value() -> None:
    probed = {
        "object": np.ones(len(VOCAB.object_atoms), bool),
        "action": np.ones(len(VOCAB.action_atoms), bool),
    }
    probed["object"][VOCAB.object_atoms.index(FLICKER)] = False
    cog = Cognition(VOCAB.object_atoms, VOCAB.action_atoms, GOAL, CognitionConfig(debounce=1), probed=probed)
    steps = [cog.step(*arrays(s)) for s in [APPROACH, APPROACH | {FLICKER}, APPROACH | {FLICKER}]]
    assert not any(s.violations or FLICKER in s.asserted for s in steps)


def test_bad_input_is_a_one_line_error() -> None:
    cog = Cognition(VOCAB.object_atoms, VOCAB.action_atoms, GOAL)
    with pytest.raises(VlaprobeError, match="expected 224 object and 12 action values"):
        cog.step(np.zeros(3, bool), np.zeros(12, bool))
    with pytest.raises(VlaprobeError, match="debounce"):
        BeliefStore(["a(x)"], debounce=0)
