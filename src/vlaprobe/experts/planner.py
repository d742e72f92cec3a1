"""The expert's planner: the BDDL goal conjunction -> an ordered list of skill steps, then the skills that run
them one after another (:class:`ScriptedExpert`).

Each conjunct becomes one step: ``Open``/``Close`` a drawer (a door such as the microwave's has no skill), ``TurnOn``/``TurnOff`` an on-off
fixture, ``In``/``On`` a movable object: a pick-and-place (by the rim for bowls and mugs, by the body for
anything else), or a push when a plate goes onto a placement region of the table. Putting something ``In`` a
drawer first opens it, after pushing the object out of the way the drawer opens over (when it stands there).
Steps run in the order clearing, opening, switching, placing, closing (a drawer is closed after what goes into
it is in).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from vlaprobe.configs.env import EnvConfig
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.experts.base import ArmSkill
from vlaprobe.symbols import Goal, Scene
from vlaprobe.symbols.goals import GoalConjunction

SkillName = Literal["clear", "open", "close", "turn_on", "turn_off", "rim_place", "body_place", "push"]
ORDER: tuple[SkillName, ...] = (
    "clear",
    "open",
    "turn_on",
    "turn_off",
    "rim_place",
    "body_place",
    "push",
    "close",
)
RIM_OBJECTS = ("bowl", "mug")
"""Instance-name parts of the objects picked by their rim (LIBERO names instances ``<category>_<n>``)."""
NO_SKILL = "the scripted expert has no skill for the goal conjunct"
PUSHED_OBJECTS = ("plate",)
"""Instance-name parts of the objects pushed, not carried, onto a placement region of the table."""
PLACES: tuple[SkillName, ...] = ("rim_place", "body_place")
"""The pick-and-place skills: ``--perturb`` acts on the object of a plan that ends with one."""


@dataclass(frozen=True)
class Step:
    """One skill to run: ``skill`` on ``subject`` (the object, region or fixture it handles), towards ``target``
    (where a placed or pushed object goes; empty otherwise)."""

    skill: SkillName
    subject: str
    target: str = ""


def _kind(name: str, parts: tuple[str, ...]) -> bool:
    return any(part in name for part in parts)


def plan_steps(goal: GoalConjunction, scene: Scene) -> list[Step]:
    """The ordered steps that make every conjunct of ``goal`` true in ``scene`` (module doc); a conjunct no
    skill handles is a VlaprobeError naming it."""
    steps: list[Step] = []
    for conjunct in goal.conjuncts:
        pred, args = conjunct.predicate, conjunct.args
        if pred in ("Open", "Close") and args[0] in scene.containers:  # drawers (doors: no skill yet)
            steps.append(Step("open" if pred == "Open" else "close", args[0]))
        elif pred in ("TurnOn", "TurnOff") and args[0] in scene.on_off:
            steps.append(Step("turn_on" if pred == "TurnOn" else "turn_off", args[0]))
        elif pred in ("In", "On") and args[0] in scene.pickupable:
            what, where = args
            if pred == "In" and where in scene.containers:
                steps.append(Step("clear", what, where))  # out from under the opened drawer (if it is)
                steps.append(Step("open", where))
            if pred == "On" and _kind(what, PUSHED_OBJECTS) and where not in scene.tabletop + scene.regions:
                steps.append(Step("push", what, where))
            else:
                steps.append(Step("rim_place" if _kind(what, RIM_OBJECTS) else "body_place", what, where))
        else:
            raise VlaprobeError(f"{NO_SKILL} {conjunct}")
    unique = list(dict.fromkeys(steps))
    return sorted(unique, key=lambda s: ORDER.index(s.skill))


def perturbation_goal(goal: GoalConjunction, scene: Scene) -> tuple[Goal | None, str]:
    """What ``--perturb`` acts on, and why nothing where it is None. A goal of one conjunct: its
    :func:`~vlaprobe.envs.bddl_scene.carried_object_goal`. Several conjuncts: that of the conjunct the plan's
    last step places (a drop hits that object while carried, a knock-off comes after the whole goal holds,
    while that pick-and-place is still the running skill); None where the plan ends otherwise (closing a
    drawer, pushing) or has no skill for a conjunct."""
    from vlaprobe.envs.bddl_scene import carried_object_goal

    if len(goal.conjuncts) == 1:
        return carried_object_goal(goal, scene), ""
    try:
        last = plan_steps(goal, scene)[-1]
    except VlaprobeError:
        return None, "the scripted expert has no plan for it"
    if last.skill not in PLACES:
        return None, f"its plan ends with {last.skill} {last.subject}, not with a pick-and-place"
    conjunct = next(
        c for c in goal.conjuncts if c.predicate in ("In", "On") and c.args == (last.subject, last.target)
    )
    chosen = carried_object_goal(GoalConjunction((conjunct,)), scene)
    return (
        chosen,
        "" if chosen is not None else f"its plan ends with {conjunct}, a place --perturb does not take",
    )


def unplannable_tasks(env: EnvConfig, tasks: tuple[int, ...]) -> dict[int, str]:
    """Of ``tasks`` of ``env.suite``, those whose goal has a conjunct no skill handles: task -> that conjunct
    (read from the BDDL files: no simulator)."""
    from vlaprobe.envs.bddl_scene import task_bddl, task_scene

    refused: dict[int, str] = {}
    for task in tasks:
        goal, scene = task_bddl(env.suite, task).goal, task_scene(env.suite, task, env.assets)
        try:
            plan_steps(goal, scene)
        except VlaprobeError as exc:
            refused[task] = str(exc).removeprefix(NO_SKILL).strip()
    return refused


def check_tasks_plannable(
    env: EnvConfig,
    tasks: tuple[int, ...],
    expert: bool,
    perturb: bool,
    *,
    chosen: bool = True,
    flag: str = "--tasks",
) -> None:
    """Before a collection: with the expert (``expert``) every task's goal must have skills, and ``--perturb``
    (``perturb``) needs a goal whose plan ends by carrying one object onto or into another (what to drop,
    displace or knock off: :func:`perturbation_goal`); one line names the task. ``chosen``: ``tasks``
    were named (``flag``); else they are the whole suite, and the line names every task left without a skill and
    the ``flag`` that selects the others."""
    from vlaprobe.envs.bddl_scene import task_bddl, task_scene

    refused = unplannable_tasks(env, tasks) if expert else {}
    if refused and chosen:
        task, conjunct = next(iter(refused.items()))
        raise VlaprobeError(f"{env.suite} task {task}: {NO_SKILL} {conjunct}; leave it out of {flag}")
    if refused:
        missing = ", ".join(f"task {t} ({c})" for t, c in refused.items())
        others = " ".join(str(t) for t in tasks if t not in refused)
        raise VlaprobeError(
            f"{env.suite}: the scripted expert has no skill for the goal conjunct of {missing}; collect the "
            f"others with {flag} {others}"
        )
    for task in tasks if perturb else ():
        problem = task_bddl(env.suite, task)
        target, why = perturbation_goal(problem.goal, task_scene(env.suite, task, env.assets))
        if target is None:
            raise VlaprobeError(
                f"--perturb needs a goal whose plan ends by carrying an object onto or into another object or a "
                f"region of a fixture (a stove, a cabinet's top, a rack, a drawer); "
                f"{env.suite} task {task}'s goal is {problem.goal}{': ' + why if why else ''}: collect it "
                f"without --perturb"
            )


def build_skill(env: LiberoTaskEnv, step: Step, seed: int) -> ArmSkill:
    """The skill object that runs ``step`` in ``env``."""
    from vlaprobe.experts.body_pick import BodyPickPlace
    from vlaprobe.experts.drawer import Drawer
    from vlaprobe.experts.knob import Knob
    from vlaprobe.experts.push import Push
    from vlaprobe.experts.rim_pick import RimPickPlace
    from vlaprobe.experts.targets import find_target

    if step.skill == "clear":
        from vlaprobe.experts.clear import Clear

        return Clear(env, step.subject, step.target, seed)
    if step.skill == "rim_place":
        return RimPickPlace(env, step.subject, find_target(env, step.target), seed)
    if step.skill == "body_place":
        return BodyPickPlace(env, step.subject, find_target(env, step.target), seed)
    if step.skill == "push":
        return Push(env, step.subject, find_target(env, step.target), seed)
    if step.skill in ("open", "close"):
        return Drawer(env, step.subject, opening=step.skill == "open", seed=seed)
    return Knob(env, step.subject, on=step.skill == "turn_on", seed=seed)


class ScriptedExpert:
    """The privileged scripted expert of a LIBERO task: runs the planned skills one after another.

    ``seed`` varies the skills' trajectories (equally valid ones). ``phase`` names the running skill's phase
    (prefixed by the skill when the plan has several)."""

    def __init__(self, env: LiberoTaskEnv, seed: int = 0) -> None:
        self.env, self.seed = env, seed
        self.steps = plan_steps(env.goal_conjunction, env.scene)
        self.skills = [build_skill(env, step, seed) for step in self.steps]
        self.reset()

    def reset(self) -> None:
        """Start a new episode (call after ``env.reset``)."""
        self._current = 0
        self.skills[0].reset()

    @property
    def phase(self) -> str:
        skill = self.skills[self._current]
        return skill.phase if len(self.skills) == 1 else f"{self.steps[self._current].skill}:{skill.phase}"

    def retarget(self, name: str) -> None:
        """Place the first pick-and-place's object on ``name`` instead of the goal's target, until the next
        reset (a fault: ``--expert-faults``)."""
        from vlaprobe.experts.rim_pick import RimPickPlace

        for skill in self.skills:
            if isinstance(skill, RimPickPlace):
                skill.retarget(name)
                return
        raise VlaprobeError("--expert-faults wrong_target needs a task whose goal puts a bowl onto something")

    def act(self) -> np.ndarray:
        """The (7,) action for the current simulator state."""
        while self.skills[self._current].done and self._current + 1 < len(self.skills):
            self._current += 1
            self.skills[self._current].reset()
        return self.skills[self._current].act()
