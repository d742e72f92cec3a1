"""The cognition's alarm: the rule on hand-made steps; alarm-driven and matched random takeovers collected on
the fake simulator through the real worker and store."""

from __future__ import annotations

import functools
from pathlib import Path

import pytest
from tests.collection.fakes import make_fake_worker

from vlaprobe.cognition.alarm import AlarmRule, CognitionSupervisor, SubgoalHandBack
from vlaprobe.cognition.core import CognitionStep, Violation
from vlaprobe.cognition.subgoals import Event, SubgoalState
from vlaprobe.collection.collect import collect
from vlaprobe.collection.store import ActivationStore
from vlaprobe.collection.takeovers import matched_counts
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.rollout.takeover import Takeover, Takeovers

NAMES = ("should-move-towards(a)", "grasped(a)", "should-move-towards(b)", "on(a,b)")


def _step(t: int, progress: float = 0.0, violations: tuple[Violation, ...] = ()) -> CognitionStep:
    return CognitionStep(t, (), (), violations, (), progress, (), False)


def test_the_alarm_fires_on_a_stall_and_counts_from_the_hand_back() -> None:
    rule = AlarmRule(stall=5, hold=3, most=3)
    fired = [t for t in range(20) if rule.check(_step(t), acting=8 <= t < 12)]
    assert fired == [5, 16]


def test_the_alarm_names_the_rules_of_a_held_violation() -> None:
    rule = AlarmRule(stall=100, hold=3, most=1)
    v = Violation("on_and_inside", "on and inside", ("on(a,b)",), since=2)
    alarms = [rule.check(_step(t, violations=(v,) if t >= 2 else ()), acting=False) for t in range(8)]
    hits = [(t, a) for t, a in enumerate(alarms) if a is not None]
    assert [t for t, _ in hits] == [4]  # held 3 steps; at most once
    assert hits[0][1].rules == ("on_and_inside",) and hits[0][1].atoms == ("on(a,b)",)


def test_an_event_fires_at_once_and_its_reason_names_the_kind_once() -> None:
    rule = AlarmRule(stall=100, hold=3, most=2)
    event = Event("regression", 3, "regression: grasped(a) no longer done")
    alarm = rule.check(CognitionStep(3, (), (), (), (), 0.0, (event,), False), acting=False)
    assert alarm is not None and alarm.kind == "regression"
    assert alarm.text() == "regression: grasped(a) no longer done"


def test_the_alarm_fires_only_on_the_kinds_it_is_given() -> None:
    """--takeover-on stall: a regression and a held violation pass; the stall still fires, counted as before."""
    event = Event("regression", 3, "regression: grasped(a) no longer done")
    v = Violation("on_and_inside", "on and inside", ("on(a,b)",), since=1)

    def run(rule: AlarmRule) -> list[tuple[int, str]]:
        steps = [CognitionStep(t, (), (), (v,), (), 0.0, (event,) if t == 3 else (), False) for t in range(8)]
        return [(t, a.kind) for t, s in enumerate(steps) if (a := rule.check(s, acting=False)) is not None]

    assert run(AlarmRule(stall=6, hold=2, most=3)) == [(2, "violation"), (3, "regression"), (4, "violation")]
    assert run(AlarmRule(stall=6, hold=2, most=3, on=("stall",))) == [(6, "stall")]
    assert run(AlarmRule(stall=6, hold=2, most=3, on=("regression",))) == [(3, "regression")]


def _level(t: int, done: int, goal: bool = False) -> CognitionStep:
    """A step whose first ``done`` subgoals are done."""
    status = ["done"] * done + ["active"] + ["pending"] * 3
    goals = tuple(SubgoalState(i + 1, n, status[i]) for i, n in enumerate(NAMES))  # type: ignore[arg-type]
    return CognitionStep(t, (), (), (), goals, done / 4, (), goal)


def test_the_hand_back_waits_for_the_subgoal_current_at_the_takeovers_start() -> None:
    back, first, second = SubgoalHandBack(), Takeover(3, "stall: x"), Takeover(9, "random")
    levels = [0, 0, 0, 1, 1, 2, 2, 2, 2, 2, 2, 3, 3]  # subgoals done at each row
    under = [None] * 3 + [first] * 3 + [None] * 3 + [second] * 3 + [None]  # the expert acts rows 3-5, 9-11
    got = {t: back.check(_level(t, n), u) for t, (n, u) in enumerate(zip(levels, under, strict=True))}
    # row 3: subgoal 2 (grasped) is current; it is done at row 5. Row 9: subgoal 3 is current, done at 11.
    assert {t: r for t, r in got.items() if r} == {
        5: "subgoal: grasped(a)",
        11: "subgoal: should-move-towards(b)",
    }
    assert SubgoalHandBack().check(_level(0, 4, goal=True), first) == "goal"
    assert SubgoalHandBack().check(_level(0, 4), None) is None  # the policy acts: nothing to hand back


def _config(out: Path, **takeover: object) -> CollectConfig:
    return CollectConfig(
        out=out,
        driver="policy",
        tasks=(0, 2),
        episodes_per_task=3,
        max_tries_per_task=3,
        keep_failed=True,
        progress=False,
        intervention=TakeoverConfig(**takeover),  # type: ignore[arg-type]
        env=EnvConfig(max_steps=30, image_size=16),
    )


def _takeovers(store: Path) -> dict[tuple[int, int], Takeovers]:
    s = ActivationStore.open(store)
    return {(e.task, e.init): s.episode(e.key).attributes.takeovers for e in s.episodes()}  # type: ignore[misc]


def _ends(t: Takeovers, cap: str) -> bool:
    """Every takeover of ``t`` handed back by the subgoal rule, the goal, its cap, or the episode's end."""
    return all(i.ended in ("goal", cap, "") or i.ended.startswith("subgoal: ") for i in t.items)


@pytest.mark.parametrize("until", ["subgoal", "steps"])
def test_random_takeovers_match_the_alarm_runs_counts(tmp_path: Path, until: str) -> None:
    cog = functools.partial(make_fake_worker, make_supervisor=CognitionSupervisor)
    steps = 3 if until == "steps" else 8
    alarm = _config(
        tmp_path / "alarm", takeover="alarm", takeover_stall=4, takeover_steps=steps, takeover_until=until
    )
    collect(alarm, cog)
    fired = _takeovers(alarm.out)
    assert any(t.items for t in fired.values()), "the fake episodes never stall: the test proves nothing"
    for t in fired.values():
        assert t.mode == "alarm" and t.until == until and all(0 <= i.steps <= steps for i in t.items)
        assert all(i.reason.split(":")[0] in ("stall", "regression", "dropped", "violation") for i in t.items)
    rand = _config(
        tmp_path / "random",
        takeover="random",
        takeover_steps=steps,
        takeover_match=alarm.out,
        takeover_until=until,
    )
    collect(rand, cog if until == "subgoal" else make_fake_worker)  # "steps": the control needs no cognition
    matched = _takeovers(rand.out)
    ended = [i.ended for t in [*fired.values(), *matched.values()] for i in t.items]
    if until == "steps":
        assert set(ended) <= {"steps", ""}
    else:  # the same rule in both conditions; the subgoal ends some takeovers before the cap
        assert all(_ends(t, "cap") for t in [*fired.values(), *matched.values()])
        assert any(e.startswith("subgoal: ") for e in ended), ended
    assert matched.keys() == fired.keys()
    assert {k: len(t.items) for k, t in matched.items()} == {k: len(t.items) for k, t in fired.items()}
    assert all(i.reason == "random" for t in matched.values() for i in t.items)
    meta = ActivationStore.open(alarm.out).metadata
    assert matched_counts(alarm.out, meta.suite, meta.model_id).keys() == fired.keys()
    with pytest.raises(VlaprobeError, match="suite libero_spatial, this collection's is libero_goal"):
        matched_counts(alarm.out, "libero_goal", meta.model_id)
    with pytest.raises(VlaprobeError, match="store of model"):
        matched_counts(alarm.out, meta.suite, "another-model")


def test_takeover_probes_must_read_the_collecting_models_hidden_states(tmp_path: Path) -> None:
    from tests.collection.fakes import FakeEnv, fake_probed_run

    fake_probed_run(tmp_path, shuffled_control=False)
    env = FakeEnv(0, EnvConfig(max_steps=6, image_size=16))
    cfg = TakeoverConfig(takeover="alarm", takeover_probes=tmp_path / "probes")
    model = ActivationStore.open(tmp_path / "activations").metadata.model_id
    assert CognitionSupervisor(env, cfg, model).readout is not None  # type: ignore[arg-type]
    with pytest.raises(VlaprobeError, match="another-model"):
        CognitionSupervisor(env, cfg, "another-model")  # type: ignore[arg-type]


def test_the_random_control_under_the_subgoal_rule_needs_the_cognition(tmp_path: Path) -> None:
    alarm = _config(tmp_path / "alarm", takeover="alarm", takeover_stall=4)
    collect(alarm, functools.partial(make_fake_worker, make_supervisor=CognitionSupervisor))
    rand = _config(tmp_path / "random", takeover="random", takeover_match=alarm.out)
    with pytest.raises(VlaprobeError, match="--takeover-until subgoal hands back by the cognition"):
        collect(rand, make_fake_worker)


def test_the_stores_settings_name_the_alarms_kinds_only_when_not_all() -> None:
    """A store collected before --takeover-on reads as every kind: its settings text is unchanged."""
    every = TakeoverConfig(takeover="alarm")
    assert "on=" not in every.text() and every.text() == (
        "alarm until=subgoal steps=150 most=3 stall=40 hold=5 atoms=truth"
    )
    assert TakeoverConfig(takeover="alarm", takeover_on=("stall",)).text().endswith(" on=stall")
