"""Subgoals of pick-and-place from the goal alone: order, progress, regression on a drop, stall."""

from __future__ import annotations

from tests.cognition.scenes import APPROACH, BOWL, CARRY, GOAL, PLACED, PLATE, VOCAB, arrays

from vlaprobe.cognition import Cognition, CognitionConfig

# the directive stays on the plate for a few steps after a release while the bowl settles (symbols/)
SETTLING = frozenset({f"should-move-towards({PLATE})"})


def run(steps: list[frozenset[str]], **config: object) -> list:
    cog = Cognition(VOCAB.object_atoms, VOCAB.action_atoms, GOAL, CognitionConfig(debounce=1, **config))
    return [cog.step(*arrays(s)) for s in steps]


def kinds(steps: list) -> list[tuple[str, int]]:
    return [(e.kind, e.t) for s in steps for e in s.events]


def test_a_clean_episode_does_the_subgoals_in_order_and_reaches_the_goal() -> None:
    steps = run([APPROACH] * 4 + [CARRY] * 5 + [SETTLING] * 2 + [PLACED] * 3)
    names = [g.name for g in steps[0].subgoals]
    assert names == [
        f"should-move-towards({BOWL})",
        f"grasped({BOWL})",
        f"should-move-towards({PLATE})",
        f"on({BOWL},{PLATE})",
    ]
    assert [g.status for g in steps[0].subgoals] == ["active", "pending", "pending", "pending"]
    assert [g.status for g in steps[4].subgoals] == ["done", "done", "active", "pending"]
    done = [e.message.split(":")[0] for s in steps for e in s.events if e.kind == "subgoal_done"]
    assert done == ["subgoal 1 done", "subgoal 2 done", "subgoal 3 done", "subgoal 4 done"]
    assert kinds(steps) == [("subgoal_done", 4)] * 2 + [("subgoal_done", 11)] * 2 + [("goal_reached", 11)]
    assert [s.progress for s in steps[3:5]] == [0.0, 0.5] and steps[-1].progress == 1.0
    assert steps[11].goal_reached and not steps[10].goal_reached
    assert all(not s.violations for s in steps)


def test_a_drop_in_mid_air_raises_a_regression() -> None:
    steps = run([APPROACH] * 3 + [CARRY] * 5 + [SETTLING] * 3 + [APPROACH] * 12, regression_steps=8)
    events = kinds(steps)
    assert ("regression", 11 + 8 - 1) in events and ("dropped", 11 + 8 - 1) in events
    assert [g.status for g in steps[-1].subgoals] == ["regressed", "regressed", "pending", "pending"]
    assert steps[-1].progress == 0.0 and not steps[-1].goal_reached
    assert not any(s.violations for s in steps)


def test_letting_go_just_above_the_place_is_not_a_drop() -> None:
    # released above the plate: grasped ends, the directive stays on the plate, the bowl lands two steps later
    steps = run([APPROACH] * 3 + [CARRY] * 5 + [SETTLING] * 2 + [PLACED] * 4, regression_steps=1)
    assert "regression" not in [k for k, _ in kinds(steps)] and steps[-1].goal_reached


def test_a_short_lapse_of_the_grasp_is_not_a_regression() -> None:
    steps = run([APPROACH] * 3 + [CARRY] * 4 + [APPROACH] * 2 + [CARRY] * 4, regression_steps=5)
    assert "regression" not in [k for k, _ in kinds(steps)]
    steps = run([APPROACH] * 3 + [CARRY] * 4 + [APPROACH] * 6, regression_steps=5)
    assert ("regression", 7 + 5 - 1) in kinds(steps)


def test_no_progress_for_stall_steps_raises_one_stalled_event() -> None:
    steps = run([APPROACH] * 25 + [CARRY] * 25, stall_steps=10)
    assert [(k, t) for k, t in kinds(steps) if k == "stalled"] == [("stalled", 10), ("stalled", 35)]


def test_a_spurious_on_during_the_carry_is_a_violation_not_the_goal() -> None:
    on = f"on({BOWL},{PLATE})"
    steps = run([APPROACH] * 3 + [CARRY] * 4 + [CARRY | {on}] * 6 + [CARRY] * 4)
    assert not any(s.goal_reached for s in steps)
    assert "goal_reached" not in [k for k, _ in kinds(steps)] and "regression" not in [
        k for k, _ in kinds(steps)
    ]
    fired = [(s.t, v.rule) for s in steps for v in s.violations if v.since == s.t]
    assert fired == [(7, "on_while_grasped")]


def test_the_goal_needs_a_grasp_before_it_and_none_while_it_holds() -> None:
    # believed on the place without any grasp: not the goal (placed_without_grasp reports it)
    steps = run([APPROACH] * 3 + [PLACED] * 5)
    assert not any(s.goal_reached for s in steps) and steps[-1].progress < 1
    # the same beliefs after a grasp and a release: the goal
    steps = run([APPROACH] * 3 + [CARRY] * 3 + [SETTLING] + [PLACED] * 3)
    assert steps[7].goal_reached and ("goal_reached", 7) in kinds(steps)
