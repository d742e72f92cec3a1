"""The collection plan: any number of workers, any completion order, any interruptions -> the serial result."""

from __future__ import annotations

import numpy as np
import pytest

from vlaprobe.collection.plan import Affinity, Plan, Unit


def serial(outcomes: dict[int, list[bool]], per_task: int, budget: int) -> dict[tuple[int, int], bool]:
    """The reference: per task, init states in order until per_task successes or the budget is spent."""
    kept = {}
    for t, row in outcomes.items():
        successes = 0
        for i in range(budget):
            if successes >= per_task:
                break
            kept[t, i] = row[i]
            successes += row[i]
    return kept


def simulate(outcomes, per_task, budget, workers, rng, store, stop_after=None):
    """Drive a Plan like collect() does, finishing running units in random order; publish kept units to
    ``store``. With ``stop_after`` events the run is killed (everything running or held is lost). Each launch
    sees a random affinity: the order it implies must not change what is kept."""
    plan = Plan(sorted(outcomes), per_task, budget, dict(store))
    running: list[Unit] = []
    events = 0
    launched = set()
    while not plan.complete():
        while len(running) < workers and (
            unit := plan.next_unit(workers > 1, random_affinity(outcomes, rng))
        ):
            assert (unit.task, unit.init) not in store and unit not in launched, unit
            launched.add(unit)
            plan.started(unit)
            running.append(unit)
        assert running, "plan stalled"
        unit = running.pop(int(rng.integers(len(running))))
        for decided, keep in plan.finished(unit, outcomes[unit.task][unit.init]):
            if keep:
                assert (decided.task, decided.init) not in store, "published twice"
                store[decided.task, decided.init] = outcomes[decided.task][decided.init]
        events += 1
        if stop_after is not None and events >= stop_after:
            return plan, False
    return plan, True


def random_affinity(outcomes: dict[int, list[bool]], rng: np.random.Generator) -> Affinity:
    tasks = list(outcomes)
    own = int(rng.choice(tasks)) if rng.random() < 0.7 else None
    return Affinity(own, frozenset(t for t in tasks if rng.random() < 0.4))


@pytest.mark.parametrize("workers", [1, 2, 3, 8])
def test_any_order_and_interruptions_give_the_serial_result(workers: int) -> None:
    rng = np.random.default_rng(workers)
    for _ in range(150):
        tasks = int(rng.integers(1, 4))
        budget = int(rng.integers(1, 12))
        per_task = int(rng.integers(1, 5))
        p_success = rng.uniform(0.2, 1.0)
        outcomes = {t: list(rng.random(budget + 3) < p_success) for t in range(tasks)}
        expected = serial(outcomes, per_task, budget)

        store: dict[tuple[int, int], bool] = {}
        plan, finished = simulate(outcomes, per_task, budget, workers, rng, store)
        assert finished and store == expected

        store = {}  # the same, killed at random points and resumed from what was published
        for _ in range(20):
            plan, finished = simulate(
                outcomes, per_task, budget, workers, rng, store, int(rng.integers(1, 6))
            )
            if finished:
                break
        else:
            plan, finished = simulate(outcomes, per_task, budget, workers, rng, store)
        assert store == expected
        for t in outcomes:
            successes = sum(ok for (task, _), ok in expected.items() if task == t)
            assert plan.kept(t) == (successes, sum(1 for task, _ in expected if task == t))
            assert plan.exhausted(t) == (successes < per_task)


def test_serial_run_decides_every_unit_at_once() -> None:
    plan = Plan([0], per_task=2, budget=10, known={})
    order = []
    while (unit := plan.next_unit()) is not None:
        plan.started(unit)
        decided = plan.finished(unit, unit.init != 1)
        assert decided == [(unit, True)]
        order.append(unit.init)
    assert order == [0, 1, 2] and plan.complete() and plan.kept(0) == (2, 3)


def test_idle_workers_speculate_and_surplus_is_dropped() -> None:
    plan = Plan([0], per_task=2, budget=10, known={})
    needed = [plan.next_unit(), None]
    plan.started(needed[0])
    needed[1] = plan.next_unit()
    plan.started(needed[1])
    assert plan.next_unit() is None  # both possibly-needed units run; nothing else is needed
    guess = plan.next_unit(speculate=True)
    assert guess == Unit(0, 2)
    plan.started(guess)
    assert plan.finished(guess, True) == []  # held: it counts only if an earlier one fails
    assert plan.finished(Unit(0, 0), True) == [(Unit(0, 0), True)]
    assert plan.finished(Unit(0, 1), True) == [(Unit(0, 1), True), (Unit(0, 2), False)]
    assert plan.complete() and plan.kept(0) == (2, 2)


def test_resume_skips_stored_units_and_honours_the_budget() -> None:
    plan = Plan([0, 1], per_task=2, budget=3, known={(0, 0): True, (0, 1): False, (1, 0): True, (1, 1): True})
    assert plan.kept(0) == (1, 2) and plan.kept(1) == (2, 2)
    unit = plan.next_unit()
    assert unit == Unit(0, 2)
    plan.started(unit)
    plan.finished(unit, False)
    assert plan.next_unit() is None and plan.complete()
    assert plan.exhausted(0) and not plan.exhausted(1)


def test_first_init_skips_the_held_out_init_states() -> None:
    """--first-init 10: init states 0-9 are never tried nor counted; the budget counts from 10."""
    known = {(0, 3): True, (0, 10): True, (0, 11): False}  # (0, 3) lies outside the span: ignored
    plan = Plan([0], per_task=3, budget=4, known=known, first=10)
    assert plan.kept(0) == (1, 2)
    order = []
    while (unit := plan.next_unit()) is not None:
        plan.started(unit)
        plan.finished(unit, unit.init != 12)
        order.append(unit.init)
    assert order == [12, 13] and plan.complete()
    assert plan.kept(0) == (2, 4) and plan.exhausted(0)  # init 14 is past the budget of 4


def test_affinity_orders_the_launches() -> None:
    """The worker's own task first, then a task no other worker holds, then the lowest task."""
    plan = Plan([0, 1, 2, 3], per_task=3, budget=10, known={})
    assert plan.next_unit() == Unit(0, 0)
    assert plan.next_unit(affinity=Affinity(own=2, others=frozenset({0}))) == Unit(2, 0)
    assert plan.next_unit(affinity=Affinity(own=None, others=frozenset({0, 1}))) == Unit(2, 0)
    assert plan.next_unit(affinity=Affinity(own=None, others=frozenset({0, 1, 2, 3}))) == Unit(0, 0)
    for i in range(3):  # task 2's needed units all run: its worker moves on to a task nobody holds
        plan.started(Unit(2, i))
    assert plan.next_unit(affinity=Affinity(own=2, others=frozenset({0}))) == Unit(1, 0)


def count_builds(workers: int, tasks: int, per_task: int, affinity: bool) -> int:
    """Simulators built by ``workers`` that finish in turn, each rebuilt when its task changes."""
    plan = Plan(list(range(tasks)), per_task, budget=10, known={})
    held: dict[int, int] = {}
    running: dict[int, Unit] = {}
    builds = turn = 0
    while not plan.complete():
        for w in range(workers):
            if w in running:
                continue
            seen = Affinity(held.get(w), frozenset(t for v, t in held.items() if v != w))
            unit = plan.next_unit(True, seen if affinity else None)
            if unit is None:
                continue
            builds += held.get(w) != unit.task
            held[w], running[w] = unit.task, unit
            plan.started(unit)
        w = sorted(running)[turn % len(running)]
        turn += 1
        plan.finished(running.pop(w), True)
    return builds


def test_affinity_builds_each_simulator_about_once() -> None:
    """make run's shape (10 tasks x 3 episodes, 2 workers): without affinity both workers build nearly every
    task's simulator; with it each task is built once, plus at most one shared task per extra worker."""
    assert count_builds(2, 10, 3, affinity=True) <= 11
    assert count_builds(2, 10, 3, affinity=False) >= 18
    assert count_builds(1, 10, 3, affinity=True) == 10
