"""Checks (b) and (c) of issue 35 in the real simulator: our goal against LIBERO's ``check_success`` and our atoms
against LIBERO's own predicates, row by row, along the settled init and along goal states reached by placing the
objects (free joints) and setting the joints (drawers, doors, knobs) directly.

:func:`place_goal` reaches a task's BDDL goal without a robot: drawers that receive an object are opened, every
``On``/``In`` object is put over its target (an object's top, a region's box), the scene settles, then every
``Open``/``Close``/``TurnOn``/``TurnOff`` joint is set inside LIBERO's range (what a drawer holds moves with it).
:func:`check_rows` compares, at every row, our goal with ``check_success`` and every atom of ours that LIBERO has a
predicate for (``on``, ``inside``, ``open``, ``turned-on``; Close/TurnOff for the goal's conjuncts) with it.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from vlaprobe.envs.libero import NOOP_ACTION, LiberoTaskEnv
from vlaprobe.policies.base import VLAPolicy
from vlaprobe.rollout import StepRecord
from vlaprobe.symbols import atom, parse_atom
from vlaprobe.symbols.goals import Conjunct, conjunct_value, goal_value

SETTLE_STEPS = 15
"""No-op steps after the objects are placed, before the joints are set."""
HOLD_STEPS = 10
"""No-op steps after the joints are set: rows checked at the goal state."""
LIBERO_NAME = {"on": "On", "inside": "In", "open": "Open", "turned-on": "TurnOn"}
"""Our predicates that LIBERO has one for."""


@dataclass
class RowCheck:
    """Counts over checked rows: goal rows, atom comparisons, and the disagreements by kind."""

    goal_rows: int = 0
    goal_reached: int = 0
    """Rows where LIBERO's ``check_success`` holds."""
    goal_undefined: int = 0
    """Rows where our goal is undefined (an ``On`` onto a workspace region: no atom of ours)."""
    atom_checks: int = 0
    placed: int = 0
    """Tasks whose placed state satisfied LIBERO's goal (``check_success`` at the last row)."""
    tasks: int = 0
    goal_wrong: list[str] = field(default_factory=list)
    atom_wrong: Counter[str] = field(default_factory=Counter)
    """Predicate-level summary of atom disagreements: ``"on(a,b) ours 1 LIBERO 0"`` -> rows."""

    def add(self, other: RowCheck) -> None:
        for name in ("goal_rows", "goal_reached", "goal_undefined", "atom_checks", "placed", "tasks"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.goal_wrong += other.goal_wrong
        self.atom_wrong.update(other.atom_wrong)


def libero_value(env: LiberoTaskEnv, name: str) -> bool | None:
    """LIBERO's own predicate for one of our object atoms (None: LIBERO has none). Our ``on(a, fixture)`` is
    LIBERO's ``On`` onto the fixture or onto one of its surface regions (its top, its cook region)."""
    pred, args = parse_atom(name)
    if pred not in LIBERO_NAME:
        return None
    if pred == "on":
        a, b = args
        onto = [b, *(r for r in env.scene.surfaces if env.scene.region_parent.get(r) == b)]
        return any(env.libero_predicate("On", a, x) for x in onto)
    return env.libero_predicate(LIBERO_NAME[pred], *args)


def check_rows(
    env: LiberoTaskEnv, label: str, out: RowCheck, success: bool, record: StepRecord | None = None
) -> None:
    """One row (the simulator's current state, or an episode's ``record`` of it): our goal vs ``success``
    (LIBERO's check), each goal conjunct and each atom vs LIBERO's predicate."""
    if record is None:
        state = env.world_state()
        values, _ = env.labeler.as_dict(state)
    else:
        assert record.world is not None
        state = record.world
        values = dict(
            zip(env.labeler.vocabulary.object_atoms, record.object_atoms.astype(int).tolist(), strict=True)
        )
    goal = env.goal_conjunction
    ours = goal_value(goal, env.scene, state, values)
    out.goal_rows += 1
    out.goal_reached += success
    if ours is None:
        out.goal_undefined += 1
    elif ours != success:
        out.goal_wrong.append(f"{label}: our goal {ours}, check_success {success} ({goal})")
    for c in goal.conjuncts:
        mine = conjunct_value(c, env.scene, state, values)
        if mine is not None:
            out.atom_checks += 1
            theirs = env.libero_predicate(c.predicate, *c.args)
            if mine != theirs:
                out.atom_wrong[f"goal {c} ours {int(mine)} LIBERO {int(theirs)}"] += 1
    for name, v in values.items():
        theirs = libero_value(env, name)
        if theirs is None:
            continue
        out.atom_checks += 1
        if bool(v) != theirs:
            out.atom_wrong[f"{name} ours {v} LIBERO {int(theirs)}"] += 1


def _joint(env: LiberoTaskEnv, name: str) -> str:
    e = env.sim_env
    return str(
        e.object_sites_dict[name].joints[0] if name in env.scene.containers else e.get_object(name).joints[0]
    )


def set_joint(env: LiberoTaskEnv, c: Conjunct) -> None:
    """Set the joint ``c`` names halfway between LIBERO's threshold and the joint's limit on the side ``c`` asks
    for; a drawer's contents move with it."""
    scene, e = env.scene, env.sim_env
    name = c.args[0]
    if name in scene.openable:
        i = scene.openable.index(name)
        opens = scene.container_articulation + scene.door_articulation
        rule = opens[i] if c.predicate == "Open" else scene.close_articulation[i]
    else:
        i = scene.on_off.index(name)
        rule = scene.on_off_articulation[i] if c.predicate == "TurnOn" else scene.off_articulation[i]
    model, data = e.sim.model, e.sim.data
    joint = _joint(env, name)
    lo, hi = model.jnt_range[model.joint_name2id(joint)]
    limit = lo if rule.below else hi
    value = (rule.threshold + limit) / 2 if hi > lo else rule.threshold + (-0.1 if rule.below else 0.1)
    inside = []
    if name in scene.containers:
        values, _ = env.labeler.as_dict(env.world_state())
        inside = [a for a in scene.pickupable if values.get(atom("inside", a, name))]
        before = np.array(data.get_site_xpos(name))
    data.set_joint_qpos(joint, value)
    data.set_joint_qvel(joint, 0.0)
    e.sim.forward()
    for a in inside:
        _shift(env, a, np.array(data.get_site_xpos(name)) - before)


def _shift(env: LiberoTaskEnv, name: str, delta: np.ndarray) -> None:
    e = env.sim_env
    joint = e.get_object(name).joints[-1]
    qpos = np.array(e.sim.data.get_joint_qpos(joint), dtype=np.float64)
    qpos[:3] += delta
    e.sim.data.set_joint_qpos(joint, qpos)
    e.sim.data.set_joint_qvel(joint, np.zeros(6))
    e.sim.forward()


def put(env: LiberoTaskEnv, a: str, target: str, into: bool) -> None:
    """Move object ``a`` over ``target``: centred on an object's origin just above its top, or on a region's
    site just above its top (``On``) or its bottom (``In``), orientation kept, at rest."""
    e, scene = env.sim_env, env.scene
    state = env.world_state()
    i = scene.tabletop.index(a)
    below = state.pos[i, 2] - state.aabb_lo[i, 2]  # origin height above the object's bottom
    if target in scene.tabletop:
        j = scene.tabletop.index(target)
        goal = np.array([*state.pos[j, :2], state.aabb_hi[j, 2] + below + 0.005])
    else:
        site = e.sim.model.site_name2id(target)
        centre = np.array(e.sim.data.site_xpos[site])
        half = float(
            np.abs(np.array(e.sim.data.site_xmat[site]).reshape(3, 3) @ e.sim.model.site_size[site])[2]
        )
        floor = centre[2] - half if into else centre[2] + half
        goal = np.array([*centre[:2], floor + below + 0.01])
    _shift(env, a, goal - state.pos[i])


def place_goal(env: LiberoTaskEnv, out: RowCheck, label: str) -> None:
    """Reach the task's goal by placing objects and setting joints; check every row on the way (see module)."""
    goal, scene = env.goal_conjunction, env.scene
    for c in goal.conjuncts:
        if c.predicate == "In" and c.args[1] in scene.containers:
            set_joint(env, Conjunct("Open", (c.args[1],)))
    moves = [c for c in goal.conjuncts if c.predicate in ("On", "In")]
    targets = {c.args[1] for c in moves}
    for c in sorted(moves, key=lambda c: c.args[0] not in targets):  # a stack's base goes first
        put(env, *c.args, into=c.predicate == "In")
    success = False
    for _ in range(SETTLE_STEPS):
        success = env.step(NOOP_ACTION).success
        check_rows(env, f"{label} settling", out, success)
    for c in goal.conjuncts:
        if c.predicate not in ("On", "In"):
            set_joint(env, c)
    for t in range(HOLD_STEPS):
        success = env.step(NOOP_ACTION).success
        check_rows(env, f"{label} goal row {t}", out, success)
    out.placed += success


def task_check(env: LiberoTaskEnv, init: int = 0) -> RowCheck:
    """One task: the settled init's rows, then the placed goal's (see module)."""
    out = RowCheck(tasks=1)
    obs = env.reset(init)
    check_rows(env, f"task {env.task_index} init {init}", out, obs.success)
    place_goal(env, out, f"task {env.task_index}")
    return out


def episode_check(
    env: LiberoTaskEnv, driver: str, policy: VLAPolicy, init: int = 0, max_steps: int = 300
) -> RowCheck:
    """Every row of one episode driven by ``driver`` (the loop collection runs), checked as it happens."""
    from vlaprobe.rollout import make_driver, run_episode

    out = RowCheck(tasks=1)
    drive = make_driver(driver, env, policy, seed=init)  # type: ignore[arg-type]
    for rec in run_episode(env, policy, drive, init=init, max_steps=max_steps, post_success_steps=5):
        check_rows(env, f"task {env.task_index} {driver} row {rec.t}", out, rec.success, rec)
    out.placed += rec.success
    return out
