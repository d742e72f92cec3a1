"""Scenes, goals and suite vocabularies read from LIBERO's BDDL files (no simulator).

A task's :class:`~vlaprobe.symbols.Scene` comes from its BDDL problem, LIBERO's object source
(:mod:`vlaprobe.envs.libero_source`: thresholds) and the asset XMLs (which regions sit on a joint), by LIBERO's
own rules:

- pickupable objects: the BDDL ``:objects``; fixtures: ``:fixtures`` except the problem class's workspace
  (``table``, ``kitchen_table``, ``floor``...), both in BDDL order;
- regions on an object or fixture (``(top_region (:target wooden_cabinet_1))`` -> ``wooden_cabinet_1_top_region``),
  in BDDL order: a region whose site sits in a body with a joint (LIBERO's ``SiteObject.joints``: the part's
  direct joints, as ``_load_sites_in_arena`` finds them) is a **container** (a drawer), with its parent's
  ``is_open``/``is_close`` rules; a region without a joint is a **receptacle** when some task of the five suites
  puts something ``In`` it (a basket, a microwave's heating region, a caddy's compartments, a shelf's layers),
  else a **surface** (a cabinet's top, a stove's cook region, a wine rack's top);
- fixtures whose category has ``is_open`` but no site of its XML on a joint are **doors** (the microwave);
  categories with ``turn_on`` are **on-off** (the flat stove; LIBERO's faucets have no turn-on rule).

Regions on the workspace (``main_table_plate_region``) are placement aids, not objects: a goal may name one
(``On(plate_1, main_table_stove_front_region)``), the vocabulary does not.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from functools import lru_cache
from pathlib import Path

from vlaprobe.configs.env import SUITES, SuiteName
from vlaprobe.envs.bddl import BddlProblem, Named, read_problem
from vlaprobe.envs.libero_source import ObjectFacts, bddl_path, libero_root, object_facts, problem_facts
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols import Articulation, Goal, Scene
from vlaprobe.symbols.goals import GoalConjunction


@lru_cache(maxsize=64)
def site_joints(xml: Path) -> dict[str, tuple[str, ...]]:
    """Site name -> joints of the body that holds it, as LIBERO's ``_load_sites_in_arena`` assigns them: every body
    under the object's root body in document order, its sites (nested ones too) and its direct joints, the last
    body that holds a site winning; stops at the first body without sites."""
    root = ET.parse(xml).getroot()
    top = root.find("worldbody/body")
    out: dict[str, tuple[str, ...]] = {}
    if top is None:
        return out
    for part in top.findall(".//body"):
        sites = part.findall(".//site")
        if not sites:
            break
        joints = tuple(j.get("name", "") for j in part.findall("./joint"))
        for site in sites:
            out[site.get("name", "")] = joints
    return out


def _category(problem: BddlProblem) -> dict[str, str]:
    return {n.name: n.category for n in problem.fixtures + problem.objects}


@lru_cache(maxsize=1)
def in_regions() -> frozenset[tuple[str, str]]:
    """(parent category, local region name) of every region some task of the five suites puts something ``In``
    (its ``:init`` or ``:goal``)."""
    found: set[tuple[str, str]] = set()
    for suite in SUITES:
        for path in sorted((libero_root() / "bddl_files" / suite).glob("*.bddl")):
            problem = read_problem(path)
            category, regions = _category(problem), {r.name: r for r in problem.regions}
            pairs = [f.args for f in problem.init if f.predicate == "in"]
            pairs += [c.args for c in problem.goal.conjuncts if c.predicate == "In"]
            for _, where in pairs:
                if where in regions and regions[where].target in category:
                    found.add((category[regions[where].target], regions[where].local))
    return frozenset(found)


def _facts(named: Named) -> ObjectFacts:
    facts = object_facts()
    if named.category not in facts:
        raise VlaprobeError(
            f"LIBERO object category {named.category!r} ({named.name}) is not registered in the installed libero "
            "package; reinstall LIBERO (`make setup`)"
        )
    return facts[named.category]


def _rule(rule: Articulation | None, what: str, named: Named) -> Articulation:
    if rule is None:
        raise VlaprobeError(f"{named.name} ({named.category}) has no {what} rule in LIBERO; not supported")
    return rule


def scene_from_problem(problem: BddlProblem, assets: Path) -> Scene:
    """The typed scene of one BDDL problem (module doc: the rules); ``assets`` holds the objects' XMLs."""
    problems = problem_facts()
    if problem.problem_class not in problems:
        raise VlaprobeError(f"unknown LIBERO problem class {problem.problem_class!r}; reinstall LIBERO")
    workspace = problems[problem.problem_class].workspace
    fixtures = tuple(f for f in problem.fixtures if f.category != workspace)
    named = {n.name: n for n in problem.objects + fixtures}
    containers: list[str] = []
    surfaces: list[str] = []
    receptacles: list[str] = []
    parents: dict[str, str] = {}
    for region in problem.regions:
        if region.target not in named:
            continue  # a placement aid on the workspace
        owner = named[region.target]
        joints = site_joints(assets / _facts(owner).xml)
        parents[region.name] = owner.name
        if joints.get(region.local):
            containers.append(region.name)
        elif (owner.category, region.local) in in_regions():
            receptacles.append(region.name)
        else:
            surfaces.append(region.name)
    doors = tuple(
        f.name
        for f in fixtures
        if _facts(f).is_open is not None and not any(site_joints(assets / _facts(f).xml).values())
    )
    on_off = tuple(f.name for f in fixtures if _facts(f).turn_on is not None)
    openers = [named[parents[c]] for c in containers] + [named[d] for d in doors]
    return Scene(
        pickupable=tuple(o.name for o in problem.objects),
        fixtures=tuple(f.name for f in fixtures),
        containers=tuple(containers),
        container_articulation=tuple(
            _rule(_facts(named[parents[c]]).is_open, "is_open", named[parents[c]]) for c in containers
        ),
        surfaces=tuple(surfaces),
        on_off=on_off,
        on_off_articulation=tuple(_rule(_facts(named[k]).turn_on, "turn_on", named[k]) for k in on_off),
        region_parent=parents,
        receptacles=tuple(receptacles),
        doors=doors,
        door_articulation=tuple(_rule(_facts(named[d]).is_open, "is_open", named[d]) for d in doors),
        close_articulation=tuple(_rule(_facts(o).is_close, "is_close", o) for o in openers),
        off_articulation=tuple(_rule(_facts(named[k]).turn_off, "turn_off", named[k]) for k in on_off),
    )


def assets_folder(assets: str | Path | None = None, suite: SuiteName = "libero_spatial") -> Path:
    """The assets folder whose XMLs say which regions sit on joints, checked for ``suite``'s files: ``assets``,
    $VLAPROBE_LIBERO_ASSETS, else the libero package's own."""
    from vlaprobe.envs.setup import resolve_assets

    folder = resolve_assets(assets, suite)
    if folder is not None:
        return folder
    own = libero_root() / "assets"
    if not own.is_dir():
        raise VlaprobeError(
            "reading a scene needs LIBERO's assets (which regions sit on a joint); set VLAPROBE_LIBERO_ASSETS "
            "(or --env.assets) to LIBERO's assets folder"
        )
    return own


def task_bddl(suite: SuiteName, task: int) -> BddlProblem:
    """The parsed BDDL problem of a suite's task (LIBERO's task order)."""
    from vlaprobe.envs.libero import _benchmark, resolve_task

    spec = _benchmark(suite).get_task(resolve_task(task, suite))
    return read_problem(bddl_path(spec.problem_folder, spec.bddl_file))


def task_scene(suite: SuiteName, task: int, assets: str | Path | None = None) -> Scene:
    """A task's scene from its BDDL file."""
    return scene_from_problem(task_bddl(suite, task), assets_folder(assets, suite))


def task_goal(suite: SuiteName, task: int) -> GoalConjunction:
    """A task's goal conjunction from its BDDL file."""
    return task_bddl(suite, task).goal


def pick_place_goal(goal: GoalConjunction, scene: Scene) -> Goal | None:
    """The pick-and-place :class:`~vlaprobe.symbols.Goal` the labeler's ``should-move-towards`` follows: a goal
    of one ``On(a, b)`` between objects of the scene (every LIBERO-spatial task); None for any other goal."""
    if len(goal.conjuncts) != 1:
        return None
    first = goal.conjuncts[0]
    if (
        first.predicate != "On"
        or first.args[0] not in scene.pickupable
        or first.args[1] not in scene.tabletop
    ):
        return None
    return Goal(pick=first.args[0], place=first.args[1])


def carried_object_goal(goal: GoalConjunction, scene: Scene) -> Goal | None:
    """The :class:`~vlaprobe.symbols.Goal` the perturbations of ``--perturb`` act on (what to drop, displace or
    knock off, and where it goes): a goal of one ``On(a, b)`` between objects of the scene (LIBERO-spatial); one
    ``In(a, r)`` where ``r`` is the receptacle region of a movable object (LIBERO-object's basket), its place then
    that object; or one ``On``/``In`` of a pickupable object onto or into a region of a fixture (a stove's cook
    region, a cabinet's top, a rack) or ``In`` a drawer, its place then the region (``WorldState.region_pos``;
    moved objects keep off the drawers' way: ``TaskEnv.drawer_fronts``). None for any other goal (pushes onto
    the table's placement regions; opening, turning on; several conjuncts: ``experts.planner.perturbation_goal``
    picks one). Only the perturbation path uses it; the labeler keeps :func:`pick_place_goal`."""
    on = pick_place_goal(goal, scene)
    if on is not None or len(goal.conjuncts) != 1:
        return on
    first = goal.conjuncts[0]
    if first.predicate not in ("On", "In") or first.args[0] not in scene.pickupable:
        return None
    what, region = first.args
    holder = scene.region_parent.get(region, "")
    if region not in scene.regions or holder == what:
        return None
    if region in scene.containers and first.predicate != "In":
        return None
    if holder in scene.pickupable:  # a movable receptacle (the basket): its origin moves with it
        return Goal(pick=what, place=holder) if first.predicate == "In" else None
    return Goal(pick=what, place=region)
