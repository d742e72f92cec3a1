"""Sampled placements (``--inits sampled``): new object layouts from a task's BDDL regions, checked after settling.

LIBERO samples a layout on every reset through robosuite's placement initializer (each object uniformly in
its ``(:init)`` region's ranges, objects on objects or inside fixture regions conditioned on them); the fixed
init states are 50 such samples saved per task. Here a reset without ``set_init_state`` draws a new one from
numpy's global generator, seeded from (suite, task, run seed, sample index, draw), so a sample index is a
reproducible placement like a fixed init state is, and another run seed gives other layouts. After the settle steps the layout is checked: nothing fell or tipped
over, nothing still moving, no two objects interpenetrating, every object still in (or on) what its
``(:init)`` condition names. A rejected draw is re-drawn (next ``draw``) and its reason kept.
"""

from __future__ import annotations

import contextlib
import hashlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

SAMPLED_INITS = 1000
"""Sample indices per task under ``--inits sampled`` (the try budget's ceiling; fixed init states: 50)."""
MAX_DRAWS = 20
"""Draws per sample index before giving up on it (the first valid draw is used)."""
REGION_SLACK = 0.05
"""How far (metres) an object's origin may end outside its table region's sampling range after settling: the
layouts LIBERO itself ships must pass. Over its 500 fixed init states of LIBERO-spatial (tasks 0-9 x 50), a bowl
whose region touches the plate's rim slides off it while settling, up to 4.1 cm outside its region (task 8; 3.9
cm task 0, 2.9 cm task 2; every other object <= 1.6 cm); the former 2 cm rejected 14 of those 500 layouts."""
PENETRATION = 0.005
"""Contact depth (metres) between two objects that counts as interpenetration."""
TIPPED = 0.35
"""Tilt (radians, ~20°) of an object's up axis between the sampled and the settled orientation that counts as
tipped over (a turn about the vertical axis alone is not: a plate or a bowl often spins while it settles)."""
MOVING = 0.05
"""Speed (m/s) of any object after settling that counts as still falling or rolling."""


@dataclass(frozen=True)
class PlacementReport:
    """How the layout of one sampled reset was found."""

    index: int
    """The sample index (the ``init`` of the episode)."""
    seed: int
    """Seed of the accepted draw: ``numpy.random.seed(seed)`` before LIBERO's reset reproduces the layout."""
    draws: int
    """Draws made; 1 when the first sample was accepted."""
    rejected: tuple[str, ...] = field(default_factory=tuple)
    """One reason per rejected draw, in order."""
    regions: tuple[tuple[str, str], ...] = ()
    """Under ``--inits sampled-swap``: (object, table region it was sampled in) where that differs from the
    task's BDDL; empty otherwise."""


def placement_seed(suite: str, task: int, seed: int, index: int, draw: int = 0) -> int:
    """The seed of draw ``draw`` of sample ``index`` of ``suite``'s ``task`` in a run seeded with ``seed``."""
    text = f"placement:{suite}:{task}:{seed}:{index}:{draw}".encode()
    return int.from_bytes(hashlib.sha256(text).digest()[:4], "little") & 0x7FFFFFFF


def _table_ranges(regions: Mapping[str, Any], name: str) -> np.ndarray | None:
    """(x0, y0, x1, y1) of a table region's sampling range, or None for a region on a fixture or object."""
    region = regions.get(name)
    if region is None or not region.get("ranges"):
        return None
    return np.asarray(region["ranges"][0], dtype=np.float64)


def sampling_problems(problem: Mapping[str, Any]) -> list[str]:
    """Why LIBERO's placement sampler cannot place this BDDL problem's objects (empty: it can).

    ``problem`` is LIBERO's parsed problem (``regions``, ``objects``, ``fixtures``, ``initial_state``): every
    movable object needs one ``(:init)`` ``On``/``In`` condition on a table region with sampling ranges, a
    fixture's region (a drawer, a cabinet's top), or another object.
    """
    regions = problem.get("regions", {})
    objects = [n for names in problem.get("objects", {}).values() for n in names]
    fixtures = {n for kind, names in problem.get("fixtures", {}).items() if kind != "table" for n in names}
    placed: dict[str, str] = {}
    for state in problem.get("initial_state", []):
        if len(state) == 3 and state[0] in ("on", "in"):
            placed[state[1]] = state[2]
    problems = []
    for name in objects:
        where = placed.get(name)
        if where is None:
            problems.append(f"{name} has no On/In condition in (:init)")
        elif where in regions:
            target = regions[where].get("target")
            if _table_ranges(regions, where) is None and target not in fixtures and target not in objects:
                problems.append(f"{name}'s region {where} has no sampling ranges")
        elif where not in objects and where not in fixtures:
            problems.append(f"{name} is placed on {where}, which is neither a region nor an object")
    return problems


def table_placements(problem: Mapping[str, Any]) -> dict[str, str]:
    """Movable object -> the table region its ``(:init)`` condition places it on (objects on other objects,
    on fixtures or in drawers are left out: they follow what they stand on)."""
    regions = problem.get("regions", {})
    movable = {n for names in problem.get("objects", {}).values() for n in names}
    return {
        s[1]: s[2]
        for s in problem.get("initial_state", [])
        if len(s) == 3 and s[0] == "on" and s[1] in movable and _table_ranges(regions, s[2]) is not None
    }


def swap_regions(
    problem: Mapping[str, Any],
    rng: np.random.Generator,
    accept: Callable[[Mapping[str, str]], bool] | None = None,
    tries: int = 200,
) -> dict[str, str]:
    """A random permutation of the table regions among the movable objects placed on them (``--inits
    sampled-swap``): object -> region. With ``accept``, permutations are drawn until one is accepted (at most
    ``tries``; then the identity, the task's own assignment). The identity is one of the permutations."""
    placed = table_placements(problem)
    names = sorted(placed)
    for _ in range(tries):
        order = rng.permutation(len(names))
        swap = {name: placed[names[j]] for name, j in zip(names, order, strict=True)}
        if accept is None or accept(swap):
            return swap
    return dict(placed)


def region_centers(
    problem: Mapping[str, Any], swap: Mapping[str, str], workspace_offset: np.ndarray
) -> dict[str, np.ndarray]:
    """Where the objects will stand before the physics: (x, y) of the middle of each table-placed object's
    region under ``swap`` (world frame), and of what an object stands on for objects on objects."""
    regions = problem.get("regions", {})
    offset = np.asarray(workspace_offset, dtype=np.float64)[:2]
    xy = {}
    for name, region in swap.items():
        ranges = _table_ranges(regions, region)
        if ranges is not None:
            xy[name] = 0.5 * (ranges[:2] + ranges[2:]) + offset
    for state in problem.get("initial_state", []):
        if len(state) == 3 and state[0] == "on" and state[2] in xy and state[1] not in xy:
            xy[state[1]] = xy[state[2]]
    return xy


@contextlib.contextmanager
def swapped_samplers(sim_env: Any, regions: Mapping[str, str] | None) -> Iterator[None]:
    """While open, LIBERO's placement sampler of each object in ``regions`` samples in the ranges of the region
    given there (the ranges of the object that region belongs to in the BDDL); restored on exit."""
    if not regions:
        yield
        return
    samplers = sim_env.placement_initializer.samplers
    owner = {region: name for name, region in table_placements(sim_env.parsed_problem).items()}
    saved = {name: (samplers[name].x_ranges, samplers[name].y_ranges) for name in regions}
    try:
        for name, region in regions.items():
            samplers[name].x_ranges, samplers[name].y_ranges = saved[owner[region]]
        yield
    finally:
        for name, (x, y) in saved.items():
            samplers[name].x_ranges, samplers[name].y_ranges = x, y


def table_center(problem: Mapping[str, Any], workspace_offset: np.ndarray) -> np.ndarray | None:
    """(x, y) of the middle of the task's table-centre region (world frame), or None without one."""
    for name in problem.get("regions", {}):
        ranges = _table_ranges(problem["regions"], name)
        if name.endswith("table_center") and ranges is not None:
            return 0.5 * (ranges[:2] + ranges[2:]) + np.asarray(workspace_offset, dtype=np.float64)[:2]
    return None


def _up(q: np.ndarray) -> np.ndarray:
    """The body z axis in the world frame of MuJoCo quaternions (w, x, y, z), row by row."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=-1)


def _tilt(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Angles (radians) between the up axes of unit quaternions, row by row: the tilt, blind to turns about the
    vertical axis."""
    return np.arccos(np.clip(np.sum(_up(q1) * _up(q2), axis=-1), -1.0, 1.0))


@dataclass(frozen=True)
class SettledLayout:
    """What the placement check reads of a settled reset (filled by the environment)."""

    names: Sequence[str]
    """The movable objects, in the order of the arrays below."""
    pos: np.ndarray
    """(N, 3) settled origins."""
    quat_sampled: np.ndarray
    """(N, 4) orientations as sampled (before settling)."""
    quat_settled: np.ndarray
    """(N, 4) orientations after settling."""
    speed: np.ndarray
    """(N,) linear speeds after settling (m/s)."""
    penetration: Mapping[tuple[str, str], float]
    """Deepest contact depth (metres, positive) per pair of objects or fixtures in contact."""
    table_height: float
    """Height of the table top."""
    workspace_offset: np.ndarray
    """(3,) LIBERO's offset of the table regions' ranges."""


def layout_problems(
    layout: SettledLayout,
    problem: Mapping[str, Any],
    holds: Mapping[str, bool],
    swapped: Mapping[str, str] | None = None,
) -> list[str]:
    """Why a settled layout is rejected (empty: accepted).

    ``holds`` maps each ``(:init)`` condition on an object or a fixture region (``"on a b"``) to whether
    LIBERO's own predicate holds now; conditions on table regions are checked here against their ranges.
    ``swapped``: object -> table region where a swap placed objects elsewhere than their ``(:init)`` says.
    """
    problems = []
    tipped = _tilt(layout.quat_sampled, layout.quat_settled)
    regions = problem.get("regions", {})
    placed = {s[1]: s[2] for s in problem.get("initial_state", []) if len(s) == 3 and s[0] in ("on", "in")}
    placed.update(swapped or {})
    for i, name in enumerate(layout.names):
        if layout.pos[i, 2] < layout.table_height - 0.05:
            problems.append(f"{name} fell off the table")
        elif tipped[i] > TIPPED:
            problems.append(f"{name} tipped over ({np.degrees(tipped[i]):.0f} deg)")
        if layout.speed[i] > MOVING:
            problems.append(f"{name} still moving ({layout.speed[i]:.2f} m/s)")
        ranges = _table_ranges(regions, placed.get(name, ""))
        if ranges is not None:
            xy = layout.pos[i, :2] - layout.workspace_offset[:2]
            lo, hi = ranges[:2] - REGION_SLACK, ranges[2:] + REGION_SLACK
            if np.any(xy < lo) or np.any(xy > hi):
                problems.append(f"{name} left its region {placed[name]}")
    for (a, b), depth in layout.penetration.items():
        if depth > PENETRATION:
            problems.append(f"{a} and {b} intersect ({depth * 1000:.0f} mm)")
    problems.extend(f"({cond}) does not hold" for cond, ok in holds.items() if not ok)
    return problems


def read_layout(
    sim_env: Any, names: Sequence[str], geom_owner: np.ndarray, quat_sampled: np.ndarray, table_height: float
) -> SettledLayout:
    """The :class:`SettledLayout` of a LIBERO environment right after its settle steps.

    ``geom_owner`` maps every geom to its object's row in ``names`` (-1 or beyond: not an object)."""
    import mujoco

    model, data = sim_env.sim.model._model, sim_env.sim.data._data
    bodies = [sim_env.obj_body_id[n] for n in names]
    vel = np.zeros(6)
    speed = np.zeros(len(names))
    for i, body in enumerate(bodies):
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, int(body), vel, 0)
        speed[i] = float(np.linalg.norm(vel[3:]))
    depth: dict[tuple[str, str], float] = {}
    n = len(names)
    for c in range(data.ncon):
        a, b = geom_owner[data.contact.geom1[c]], geom_owner[data.contact.geom2[c]]
        if 0 <= a < n and 0 <= b < n and a != b:
            pair = (names[min(a, b)], names[max(a, b)])
            depth[pair] = max(depth.get(pair, 0.0), -float(data.contact.dist[c]))
    return SettledLayout(
        names=tuple(names),
        pos=data.xpos[bodies].copy(),
        quat_sampled=quat_sampled,
        quat_settled=data.xquat[bodies].copy(),
        speed=speed,
        penetration=depth,
        table_height=table_height,
        workspace_offset=np.asarray(sim_env.workspace_offset, dtype=np.float64),
    )


def init_conditions_hold(sim_env: Any, problem: Mapping[str, Any]) -> dict[str, bool]:
    """LIBERO's own predicate for every ``(:init)`` On/In condition whose target is an object or a fixture's
    region (table regions have no such check in LIBERO: :func:`layout_problems` tests their ranges)."""
    regions = problem.get("regions", {})
    holds = {}
    for state in problem.get("initial_state", []):
        if len(state) != 3 or state[0] not in ("on", "in"):
            continue
        if _table_ranges(regions, state[2]) is not None:
            continue
        holds[" ".join(state)] = bool(sim_env._eval_predicate(list(state)))
    return holds
