"""Perturbations: the spec, free spots on hand-made worlds, when a Perturber fires, and the loop applying it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from tests.collection.fakes import GOAL, SCENE, FakeEnv, FakeExpert, FakePolicy, succeeds

from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.rollout import EpisodeControl, run_episode
from vlaprobe.rollout.perturb import (
    CLEARANCE,
    DROP_STEPS,
    KNOCK_ROOM,
    KNOCK_WAIT,
    REACH,
    WORKSPACE,
    Perturber,
    PerturbSpec,
    free_spot,
    nearest_free_spot,
)
from vlaprobe.symbols import Goal, WorldState


def test_spec_parses_kinds_and_refuses_unknown_kinds_and_bad_probabilities() -> None:
    assert PerturbSpec.parse("") == PerturbSpec() and not PerturbSpec().any
    spec = PerturbSpec.parse("drop=0.5, knock-off=1")
    assert spec == PerturbSpec(drop=0.5, knock_off=1.0) and spec.any and spec.text() == "drop=0.5,knock_off=1"
    with pytest.raises(VlaprobeError, match="unknown perturbation 'shake'"):
        PerturbSpec.parse("shake=0.2")
    for bad in ("drop=1.5", "drop=-0.1", "drop=x", "drop", "drop=nan"):
        with pytest.raises(VlaprobeError, match="needs a probability in \\[0, 1\\]"):
            PerturbSpec.parse(bad)


def test_spec_refuses_a_kind_given_twice() -> None:
    for twice in ("drop=0.2,drop=0.9", "knock_off=1, knock-off=0.5"):
        with pytest.raises(VlaprobeError, match="is given twice"):
            PerturbSpec.parse(twice)


def world(pos: np.ndarray, half: float = 0.04) -> WorldState:
    env = FakeEnv(0, None)
    env.reset(0)
    return dataclasses.replace(env.world_state(), pos=pos, aabb_lo=pos - half, aabb_hi=pos + half)


def test_free_spot_keeps_clear_of_every_other_object_and_inside_the_workspace() -> None:
    pos = np.array([[0.0, 0.0, 0.94], [0.1, 0.1, 0.94], [-0.1, 0.2, 0.94]])
    w = world(pos)
    rng = np.random.default_rng(0)
    for _ in range(50):
        xy = free_spot(w, 0, rng)
        assert xy is not None
        assert np.all(xy >= WORKSPACE[0]) and np.all(xy <= WORKSPACE[1])
        for j in (1, 2):  # footprints (8 cm boxes) apart by at least the clearance on one axis
            assert np.max(np.abs(xy - pos[j, :2])) >= 0.08 + CLEARANCE - 1e-9
    near = free_spot(w, 0, rng, near=pos[1])
    assert near is not None and 0.12 <= np.linalg.norm(near - pos[1, :2]) <= 0.22
    crowded = world(pos, half=0.5)  # every spot overlaps another object
    assert free_spot(crowded, 0, rng) is None


def test_perturber_draws_from_the_seed_and_fires_at_its_moments() -> None:
    always = PerturbSpec(drop=1.0, displace=1.0, knock_off=1.0)
    a, b = Perturber(always, 3, SCENE, GOAL), Perturber(always, 3, SCENE, GOAL)
    assert [(p.kind, p.after) for p in a.planned] == [(p.kind, p.after) for p in b.planned]
    assert [p.kind for p in a.planned] == ["drop", "displace", "knock_off"]
    assert Perturber(PerturbSpec(), 3, SCENE, GOAL).planned == []
    on_table = np.array([[0.0, 0.0, 0.94], [0.1, 0.1, 0.94], [-0.1, 0.2, 0.94]])
    lifted = on_table + np.array([0.0, 0.0, 0.1])
    control, fired = EpisodeControl(), []
    displace, drop, knock = (a.planned[1].after, a.planned[0].after, a.planned[2].after)
    t = 0
    for _ in range(displace + 2):  # before the grasp: the displacement fires at its row
        fired.append((t, a.observe(t, world(on_table), False, False, control)))
        t += 1
    assert [k for _, k in fired if k] == ["displace"] and fired[displace][1] == "displace"
    assert control.take_move() is not None and a.planned[1].row == displace + 1
    for _ in range(drop):  # held and lifted: the drop fires after `drop` such rows
        assert a.observe(t, world(lifted), True, False, control) == ""
        t += 1
    assert a.observe(t, world(lifted), True, False, control) == "drop"
    assert [control.take_drop() for _ in range(DROP_STEPS + 1)] == [True] * DROP_STEPS + [False]
    t += 1
    for _ in range(knock):  # success with nothing grasped: the knock-off fires after `knock` rows
        assert a.observe(t, world(on_table), False, True, control) == ""
        t += 1
    assert control.success_hold == KNOCK_WAIT  # the knock-off is still to come: a success is held open
    assert a.observe(t, world(on_table), False, True, control) == "knock_off"
    assert control.success_hold == 0
    name, xy = control.take_move()  # type: ignore[misc]
    assert name == GOAL.pick and 0.12 <= np.linalg.norm(np.asarray(xy) - on_table[1, :2]) <= 0.22
    assert a.observe(t + 1, world(on_table), False, True, control) == ""  # each fires once


def test_the_loop_applies_a_move_before_the_next_observation_and_marks_the_row() -> None:
    init = next(i for i in range(12) if succeeds(0, i))
    env, control = FakeEnv(0, None), EpisodeControl()
    rows = []
    for r in run_episode(
        env, FakePolicy(PolicyConfig()), FakeExpert(env, 0), init=init, max_steps=20, control=control
    ):
        rows.append(r)
        if r.t == 0:
            control.move("bowl", (0.05, 0.1))
    assert env.moves == [(1, "bowl", (0.05, 0.1))]
    assert [r.perturbation for r in rows[:3]] == ["", "move", ""] and rows[1].perturbed


def test_a_pending_knock_off_holds_the_success_open_and_nothing_else_does() -> None:
    held, free = EpisodeControl(), EpisodeControl()
    w = world(np.array([[0.0, 0.0, 0.94], [0.1, 0.1, 0.94], [-0.1, 0.2, 0.94]]))
    Perturber(PerturbSpec(knock_off=1.0), 3, SCENE, GOAL).observe(0, w, False, False, held)
    Perturber(PerturbSpec(drop=1.0, displace=1.0), 3, SCENE, GOAL).observe(0, w, False, False, free)
    assert held.success_hold == KNOCK_WAIT and free.success_hold == 0
    with pytest.raises(VlaprobeError, match="0 or more rows"):
        held.hold_success(-1)


@pytest.mark.parametrize("hold", [0, 3])
def test_the_loop_ends_a_held_success_after_the_hold(hold: int) -> None:
    init = next(i for i in range(12) if succeeds(0, i))
    env, control = FakeEnv(0, None), EpisodeControl()
    control.hold_success(hold)
    rows = list(
        run_episode(
            env, FakePolicy(PolicyConfig()), FakeExpert(env, 0), init=init, max_steps=40, control=control
        )
    )
    onset = next(r.t for r in rows if r.success)
    assert rows[-1].terminal and rows[-1].t == onset + hold and all(r.success for r in rows[onset:])


def test_a_fixture_region_place_is_read_from_the_region_sites() -> None:
    """Onto a fixture's region: the knock-off lands 12-22 cm from the region's site, not from an object."""
    pos = np.array([[0.0, 0.0, 0.94], [0.1, 0.1, 0.94], [-0.1, 0.2, 0.94]])
    w = dataclasses.replace(world(pos), region_pos=np.array([[-0.05, 0.05, 1.0]]))
    perturber = Perturber(PerturbSpec(knock_off=1.0), 3, SCENE, Goal(pick="bowl", place="cabinet_top"))
    assert np.array_equal(perturber.place_point(w), [-0.05, 0.05, 1.0])
    control, t = EpisodeControl(), 0
    while not perturber.observe(t, w, False, True, control):
        t += 1
    _, xy = control.take_move()  # type: ignore[misc]
    assert 0.12 <= np.linalg.norm(np.asarray(xy) - [-0.05, 0.05]) <= 0.22


def test_moved_objects_land_within_reach_of_the_robot_base() -> None:
    pos = np.array([[0.0, 0.0, 0.94], [0.1, 0.1, 0.94], [-0.1, 0.2, 0.94]])
    w, base = world(pos, half=0.02), (-0.66, 0.0)
    rng = np.random.default_rng(0)
    spots = [free_spot(w, 0, rng, base=base) for _ in range(300)]
    far = [free_spot(w, 0, rng) for _ in range(300)]
    assert all(s is not None and np.linalg.norm(s - base) <= REACH for s in spots)
    assert any(s is not None and np.linalg.norm(s - base) > REACH for s in far)  # the table's far corner


def test_a_knock_off_without_a_free_spot_is_given_up_and_releases_the_hold() -> None:
    crowded = world(np.array([[0.0, 0.0, 0.94], [0.1, 0.1, 0.94], [-0.1, 0.2, 0.94]]), half=0.5)
    perturber, control = Perturber(PerturbSpec(knock_off=1.0), 3, SCENE, GOAL), EpisodeControl()
    kinds = [perturber.observe(t, crowded, False, True, control) for t in range(8)]
    assert kinds == [""] * 8 and perturber.planned[0].missed and perturber.planned[0].row is None
    assert control.success_hold == 0 and control.take_move() is None
    (miss,) = perturber.unapplied()
    assert miss.reason.startswith("no free spot:") and miss.missed_row == 1  # due after 2 success rows


def test_a_knock_off_too_late_for_the_budget_is_given_up_and_one_in_time_comes() -> None:
    """A knock-off due with fewer than KNOCK_ROOM actions left would fail a succeeded episode: given up."""
    w = world(np.array([[0.0, 0.0, 0.94], [0.1, 0.1, 0.94], [-0.1, 0.2, 0.94]]))
    spec = PerturbSpec(knock_off=1.0)
    late, control = Perturber(spec, 3, SCENE, GOAL, max_steps=KNOCK_ROOM + 5), EpisodeControl()
    start = 10  # success from row 10 on: its knock-off comes due with fewer than KNOCK_ROOM actions left
    kinds = [late.observe(t, w, False, True, control) for t in range(start, start + 8)]
    assert kinds == [""] * 8 and late.planned[0].missed and control.success_hold == 0
    (miss,) = late.unapplied()
    due = start + miss.after  # the row its success rows were complete at
    left = KNOCK_ROOM + 5 - due
    assert (
        miss.missed_row == due
        and miss.reason == f"too late: {left} actions left, a recovery needs {KNOCK_ROOM}"
    )
    early, control = Perturber(spec, 3, SCENE, GOAL, max_steps=KNOCK_ROOM + 30), EpisodeControl()
    kinds = [early.observe(t, w, False, True, control) for t in range(start, start + 8)]
    assert "knock_off" in kinds and not early.planned[0].missed and early.unapplied() == []


def test_perturbations_whose_moment_never_came_say_why() -> None:
    """Read after the last row, every drawn perturbation that did not happen names why its trigger never held."""
    w = world(np.array([[0.0, 0.0, 0.94], [0.1, 0.1, 0.94], [-0.1, 0.2, 0.94]]))
    spec = PerturbSpec(drop=1.0, displace=1.0, knock_off=1.0)
    perturber, control = Perturber(spec, 3, SCENE, GOAL), EpisodeControl()
    for t in range(2):  # two rows, nothing grasped, no success: the episode ends before any trigger
        assert perturber.observe(t, w, False, False, control) == ""
    reasons = {p.kind: p.reason for p in perturber.unapplied()}
    displace_row = next(p.after for p in perturber.planned if p.kind == "displace")
    assert reasons == {
        "drop": f"never due: the object was held lifted and away from the target for 0 rows, "
        f"{next(p.after for p in perturber.planned if p.kind == 'drop') + 1} wanted",
        "displace": f"never due: the episode ended at row 1, before row {displace_row}",
        "knock_off": "never due: the task never succeeded with nothing grasped",
    }
    assert all(p.missed_row is None and not p.missed for p in perturber.planned)
    grasped = Perturber(PerturbSpec(displace=1.0), 3, SCENE, GOAL)
    for t in range(30):  # grasped from row 0 on: the displacement's row passes with the object in hand
        grasped.observe(t, w, True, False, EpisodeControl())
    (miss,) = grasped.unapplied()
    assert miss.reason == f"never due: the object was grasped before row {miss.after}"


def test_a_knock_off_from_a_crowded_fixture_lands_at_the_nearest_free_spot() -> None:
    """No spot 12-22 cm from the region's site is free (object 1 covers them): the nearest free one is taken,
    for a fixture's region only (a knock-off off an object is given up, so spatial draws stay as they were)."""
    pos = np.array([[0.0, 0.27, 0.94], [0.0, 0.0, 0.94], [-0.2, 0.28, 0.94]])
    half = np.array([[0.01, 0.01, 0.01], [0.23, 0.23, 0.01], [0.01, 0.01, 0.01]])
    w = dataclasses.replace(world(pos), aabb_lo=pos - half, aabb_hi=pos + half, region_pos=np.zeros((1, 3)))
    rng = np.random.default_rng(0)
    assert free_spot(w, 0, rng, near=np.zeros(3)) is None
    xy = nearest_free_spot(w, 0, rng, np.zeros(3))
    assert xy is not None and xy[1] >= 0.23 + CLEARANCE + 0.01
    # the free band y in [0.26, 0.30] (5 cm around the object's own spot excluded) lies 0.26-0.37 m from the
    # site: the nearest of 400 draws is near its low end
    assert np.linalg.norm(xy) < 0.31
    for place, moved in (("cabinet_top", True), ("plate", False)):
        perturber, control = (
            Perturber(PerturbSpec(knock_off=1.0), 3, SCENE, Goal("bowl", place)),
            EpisodeControl(),
        )
        kinds = [perturber.observe(t, w, False, True, control) for t in range(8)]
        assert ("knock_off" in kinds) is moved and perturber.planned[0].missed is not moved
