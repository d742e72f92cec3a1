"""Perturbations during an episode (``--perturb SPEC``): drop the grasped object, displace it before the grasp,
knock it off its place target after placement.

A :class:`PerturbSpec` gives each kind a probability per episode. :class:`Perturber` draws, from the
episode's seed, which kinds an episode gets and when, watches the records of the one step loop
(:func:`vlaprobe.rollout.run_episode`) and asks its :class:`~vlaprobe.rollout.loop.EpisodeControl` for the
perturbation at the chosen moment: ``drop`` is the control's existing forced gripper opening; ``displace``
and ``knock_off`` move the object to a free spot on the table (the loop applies the move between two steps and
observes again). The driver sees only the consequences (the expert re-plans: it re-grasps a dropped or
displaced object and picks a knocked-off one up again); detectors and cognition read the real simulator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from vlaprobe.envs.base import TaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.rollout.loop import EpisodeControl
from vlaprobe.symbols import Goal, Scene, WorldState

KINDS = ("drop", "displace", "knock_off")
"""Perturbation kinds, in the order their draws are made."""
KIND_CODE = {kind: i + 1 for i, kind in enumerate(KINDS)}
"""Code of each kind in the store's per-step ``perturbation`` array (0: none)."""
DROP_STEPS = 8
"""Steps the gripper is forced open for a drop (the live monitor's drop button uses the same)."""
LIFTED = 0.04
"""Height (metres) of the held object's bottom above the table from which a drop may happen."""
WORKSPACE = ((-0.22, -0.20), (0.16, 0.30))
"""(x, y) low and high corners of the table area a moved object may land in (the robot's reach)."""
CLEARANCE = 0.02
"""Gap (metres) kept between a moved object's footprint and every other object's."""
DROP_AWAY = 0.12
"""Least horizontal distance (metres) of the held object from the place target for a drop: it falls onto the
table, not onto the target (which would end the task without a re-grasp)."""
KNOCK_DISTANCE = (0.12, 0.22)
"""Distance range (metres) of a knocked-off object's landing spot from the place target's origin."""
REACH = 0.80
"""Greatest horizontal distance (metres) of a moved object's landing spot from the robot's base: the farthest
LIBERO's own init states put an object (0.805 m, LIBERO-spatial task 1; LIBERO-goal 0.725, LIBERO-object 0.755).
Beyond it the expert cannot reach the object (LIBERO-goal's displacements to 0.84-0.86 m were never grasped)."""
KNOCK_WAIT = 80
"""Rows after the success onset an episode with a knock-off still to come is held open for: the knock-off waits
for the release (an ``In`` goal holds on contact, ~45 rows before the expert lets go; with
``--post-success-steps 0`` the success row would otherwise end the episode). After it the episode ends."""
Box = tuple[np.ndarray, np.ndarray]
"""(x, y) low and high corners of a table area no moved object may overlap (a drawer's way: ``keep_out``)."""
KNOCK_ROOM = 140
"""Least actions left in the episode's budget for a knock-off to come: the expert's recovery (walk back, pick,
carry, place) took 105-136 rows on LIBERO-object; a knock-off later than that fails an episode that had
succeeded, so it is given up (its hold released)."""


def parse_kinds(
    text: str, flag: str, noun: str, kinds: tuple[str, ...], example: str, scales: tuple[str, ...] = ()
) -> dict[str, float]:
    """``"kind=value,..."`` (``-`` or ``_`` in kinds) as {kind: value}: probabilities in [0, 1], or for the
    kinds in ``scales`` any value ≥ 0; a one-line error naming ``flag`` otherwise."""
    values: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        kind, sep, value = part.partition("=")
        kind = kind.strip().replace("-", "_")
        if kind not in kinds:
            use = "kind=probability" if not scales else "kind=value"
            raise VlaprobeError(
                f"{flag}: unknown {noun} {kind!r}; use {use} with kinds {', '.join(kinds)} (e.g. {example})"
            )
        try:
            v = float(value) if sep else float("nan")
        except ValueError:
            v = float("nan")
        top = float("inf") if kind in scales else 1.0
        if not 0.0 <= v <= top:
            what = "a scale ≥ 0" if kind in scales else "a probability in [0, 1]"
            raise VlaprobeError(f"{flag}: {kind} needs {what}, got {value.strip()!r}")
        if kind in values:
            raise VlaprobeError(
                f"{flag}: {kind} is given twice ({values[kind]:g} and {v:g}); give each kind once"
            )
        values[kind] = v
    return values


@dataclass(frozen=True)
class PerturbSpec:
    """Probability per episode of each perturbation kind (``--perturb drop=0.5,knock_off=0.3``)."""

    drop: float = 0.0
    displace: float = 0.0
    knock_off: float = 0.0

    @classmethod
    def parse(cls, text: str, flag: str = "--perturb") -> PerturbSpec:
        """``"kind=p,kind=p"`` with kinds from :data:`KINDS` and p in [0, 1]; "" is no perturbation."""
        return cls(**parse_kinds(text, flag, "perturbation", KINDS, "drop=0.5,knock_off=0.3"))

    @property
    def any(self) -> bool:
        return any(getattr(self, k) > 0 for k in KINDS)

    def text(self) -> str:
        return ",".join(f"{k}={getattr(self, k):g}" for k in KINDS if getattr(self, k) > 0)


@dataclass
class Planned:
    """One perturbation an episode gets: its kind, its trigger and, once applied, the row it hit."""

    kind: str
    after: int
    """drop: held rows with the object lifted and away from the target before it; displace: the row (if still before the grasp);
    knock_off: rows after success (with nothing grasped) before it."""
    row: int | None = None
    """The row at which it was applied (None: not applied)."""
    missed_row: int | None = None
    """The row at which it was given up (None: not given up)."""
    reason: str = ""
    """Why it was not applied, "<class>: <details>" (classes: "too late", "no free spot", "never due"); set when
    it is given up, or by :meth:`Perturber.unapplied` for one whose moment never came; "" while still to come."""

    @property
    def missed(self) -> bool:
        """Its moment came but it was given up: no free spot within reach, or (a knock-off) fewer than
        :data:`KNOCK_ROOM` actions left."""
        return self.missed_row is not None


def free_spot(
    world: WorldState,
    index: int,
    rng: np.random.Generator,
    near: np.ndarray | None = None,
    base: tuple[float, float] | None = None,
    tries: int = 200,
    keep_out: tuple[Box, ...] = (),
) -> np.ndarray | None:
    """An (x, y) on the table where object ``index``'s footprint keeps :data:`CLEARANCE` from every other
    object (its current spot excluded by 5 cm), inside :data:`WORKSPACE` and, with ``base`` (the robot's base),
    within :data:`REACH` of it; with ``near``, at a distance in :data:`KNOCK_DISTANCE` of that point; off every box
    of ``keep_out``. None when no spot is found."""
    lo, hi = np.array(WORKSPACE[0]), np.array(WORKSPACE[1])
    for _ in range(tries):
        if near is None:
            xy = rng.uniform(lo, hi)
        else:
            angle, dist = rng.uniform(0, 2 * np.pi), rng.uniform(*KNOCK_DISTANCE)
            xy = near[:2] + dist * np.array([np.cos(angle), np.sin(angle)])
        if _free(world, index, xy, base, keep_out):
            return xy
    return None


def nearest_free_spot(
    world: WorldState,
    index: int,
    rng: np.random.Generator,
    near: np.ndarray,
    base: tuple[float, float] | None = None,
    tries: int = 400,
    keep_out: tuple[Box, ...] = (),
) -> np.ndarray | None:
    """Of ``tries`` spots drawn over :data:`WORKSPACE`, the free one (as in :func:`free_spot`) nearest ``near``:
    where a fixture stands among other things (LIBERO-goal's cabinet between the plate and the rack) no spot
    within :data:`KNOCK_DISTANCE` of its region is free. None when none is free."""
    lo, hi = np.array(WORKSPACE[0]), np.array(WORKSPACE[1])
    spots = [xy for xy in rng.uniform(lo, hi, size=(tries, 2)) if _free(world, index, xy, base, keep_out)]
    if not spots:
        return None
    return min(spots, key=lambda xy: float(np.linalg.norm(xy - near[:2])))


def _free(
    world: WorldState,
    index: int,
    xy: np.ndarray,
    base: tuple[float, float] | None,
    keep_out: tuple[Box, ...] = (),
) -> bool:
    """Whether object ``index`` may land with its origin at ``xy`` (the conditions of :func:`free_spot`)."""
    lo, hi = np.array(WORKSPACE[0]), np.array(WORKSPACE[1])
    if np.any(xy < lo) or np.any(xy > hi) or np.linalg.norm(xy - world.pos[index, :2]) < 0.05:
        return False
    if base is not None and np.linalg.norm(xy - np.asarray(base)) > REACH:
        return False
    half = 0.5 * (world.aabb_hi[index, :2] - world.aabb_lo[index, :2])
    centre_off = world.pos[index, :2] - 0.5 * (world.aabb_hi[index, :2] + world.aabb_lo[index, :2])
    box_lo, box_hi = xy - centre_off - half - CLEARANCE, xy - centre_off + half + CLEARANCE
    if any(np.all(box_hi >= k_lo) and np.all(box_lo <= k_hi) for k_lo, k_hi in keep_out):
        return False
    return all(
        np.any(box_hi < world.aabb_lo[j, :2]) or np.any(box_lo > world.aabb_hi[j, :2])
        for j in range(len(world.pos))
        if j != index
    )


@dataclass
class Perturber:
    """Which perturbations one episode gets and when (drawn from its seed), applied through its control."""

    spec: PerturbSpec
    seed: int
    scene: Scene
    goal: Goal
    base: tuple[float, float] | None = None
    """(x, y) of the robot's base: moved objects land within :data:`REACH` of it (None: anywhere on the table)."""
    max_steps: int | None = None
    """The episode's action budget: a knock-off with fewer than :data:`KNOCK_ROOM` actions left is given up
    (None: no budget)."""
    keep_out: Callable[[], tuple[Box, ...]] | None = None
    """The table areas a moved object may not land in, read when a move is due (the fronts of the scene's drawers
    where the goal goes into one: ``TaskEnv.drawer_fronts``); None: none."""
    planned: list[Planned] = field(default_factory=list)

    def __post_init__(self) -> None:
        rng = np.random.default_rng([self.seed, 7919])
        self.rng = np.random.default_rng([self.seed, 104729])
        triggers = {"drop": (1, 6), "displace": (3, 25), "knock_off": (1, 4)}
        for kind in KINDS:
            hit = rng.random() < getattr(self.spec, kind)
            after = int(rng.integers(*triggers[kind]))
            if hit:
                self.planned.append(Planned(kind, after))
        self._pick = self.scene.tabletop.index(self.goal.pick)
        self._held_lifted = 0
        self._grasped_ever = False
        self._success_rows = 0
        self._success_run = 0  # the longest run of rows succeeded with nothing grasped
        self._rows = 0

    def place_point(self, world: WorldState) -> np.ndarray:
        """(3,) where the carried object goes: the place object's origin, or the fixture region's site."""
        if self.goal.place in self.scene.tabletop:
            return np.asarray(world.pos[self.scene.tabletop.index(self.goal.place)])
        return np.asarray(world.region_pos[self.scene.regions.index(self.goal.place)])

    def observe(
        self, t: int, world: WorldState, grasped: bool, success: bool, control: EpisodeControl
    ) -> str:
        """Look at row ``t`` (its world, whether the pick object is grasped, the task's success); request
        the perturbation due now from ``control``. Returns the kind requested, or "".

        While a knock-off is still to come, ``control`` holds a success open for :data:`KNOCK_WAIT` rows (set
        from the first row on: the success row may be the last one otherwise)."""
        self._grasped_ever |= grasped
        self._rows = t + 1
        lifted = world.aabb_lo[self._pick, 2] - world.table_height > LIFTED
        place = self.place_point(world)
        away = np.linalg.norm(world.pos[self._pick, :2] - place[:2]) > DROP_AWAY
        self._held_lifted += int(grasped and lifted and away)
        self._success_rows = self._success_rows + 1 if success and not grasped else 0
        self._success_run = max(self._success_run, self._success_rows)
        kind = ""
        for p in self.planned:
            if p.row is not None or p.missed:
                continue
            if p.kind == "drop" and grasped and lifted and away and self._held_lifted > p.after:
                control.drop(DROP_STEPS)
            elif p.kind in ("displace", "knock_off") and self._due(p, t):
                if p.kind == "knock_off" and self.max_steps is not None and self.max_steps - t < KNOCK_ROOM:
                    left = self.max_steps - t  # too late to recover within the budget
                    self._give_up(p, t, f"too late: {left} actions left, a recovery needs {KNOCK_ROOM}")
                    continue
                near = place if p.kind == "knock_off" else None
                out = self.keep_out() if self.keep_out is not None else ()
                xy = free_spot(world, self._pick, self.rng, near=near, base=self.base, keep_out=out)
                if xy is None and p.kind == "knock_off" and self.goal.place not in self.scene.tabletop:
                    xy = nearest_free_spot(world, self._pick, self.rng, place, base=self.base, keep_out=out)
                if xy is None:
                    way = " off the drawers' way" if out else ""
                    self._give_up(p, t, f"no free spot: none within {REACH:g} m of the robot's base{way}")
                    continue
                control.move(self.goal.pick, xy)
            else:
                continue
            p.row, kind = t + 1, p.kind  # the next observation is the first one the perturbation changed
            break
        waiting = any(p.kind == "knock_off" and p.row is None and not p.missed for p in self.planned)
        control.hold_success(KNOCK_WAIT if waiting else 0)
        return kind

    @staticmethod
    def _give_up(p: Planned, t: int, reason: str) -> None:
        p.missed_row, p.reason = t, reason

    def unapplied(self) -> list[Planned]:
        """The planned perturbations not applied, each with its :attr:`Planned.reason`: given up, or (read after
        the episode's last row) never due."""
        out = [p for p in self.planned if p.row is None]
        for p in out:
            if not p.missed:
                p.reason = f"never due: {self._never_due(p)}"
        return out

    def _never_due(self, p: Planned) -> str:
        """Why the moment of ``p`` did not come in the rows observed."""
        if p.kind == "drop":
            return (
                f"the object was held lifted and away from the target for {self._held_lifted} rows, "
                f"{p.after + 1} wanted"
            )
        if p.kind == "displace":
            if self._rows <= p.after:
                return f"the episode ended at row {self._rows - 1}, before row {p.after}"
            return f"the object was grasped before row {p.after}"
        if not self._success_run:
            return "the task never succeeded with nothing grasped"
        return (
            f"the success with nothing grasped lasted at most {self._success_run} rows, {p.after + 1} wanted"
        )

    def _due(self, p: Planned, t: int) -> bool:
        """A displacement at its row while nothing has been grasped yet; a knock-off after its success rows."""
        if p.kind == "displace":
            return not self._grasped_ever and t == p.after
        return self._success_rows > p.after


def perturb_target(env: TaskEnv) -> Goal | None:
    """What ``--perturb`` acts on in ``env``: ``env.perturb_goal`` (a goal of one conjunct), else, for a goal of
    several, the object the expert's plan places last (:func:`~vlaprobe.experts.planner.perturbation_goal`)."""
    if env.perturb_goal is not None or len(env.goal_conjunction.conjuncts) < 2:
        return env.perturb_goal
    from vlaprobe.experts.planner import perturbation_goal

    return perturbation_goal(env.goal_conjunction, env.scene)[0]


def episode_perturber(spec: PerturbSpec, seed: int, env: TaskEnv, max_steps: int) -> Perturber | None:
    """The episode's perturber (None without ``--perturb``) as collection, live runs and benches build it: acting
    on :func:`perturb_target`, moved objects within reach of ``env.robot_base`` (and, into a drawer, off the
    drawers' way: ``env.drawer_fronts``), within the episode's budget of ``max_steps`` actions."""
    if not spec.any:
        return None
    goal = perturb_target(env)
    if goal is None:  # check_tasks_plannable refuses such tasks before a collection
        raise VlaprobeError(
            f"--perturb: task {env.task_index}'s goal carries no one object onto or into another"
        )
    keep_out = env.drawer_fronts if goal.place in env.scene.containers else None  # other goals: as before
    return Perturber(spec, seed, env.scene, goal, env.robot_base, max_steps, keep_out)
