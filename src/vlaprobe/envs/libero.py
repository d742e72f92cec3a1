"""LIBERO task environments: the suite's tasks, fixed or sampled init states, settled resets, steps, images.

One :class:`LiberoTaskEnv` wraps one LIBERO task (an ``OffScreenRenderEnv``). What the scene is (its typed
objects and goal) and where it stands (world-state snapshots) are read by :mod:`vlaprobe.envs.libero_world`.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping
from functools import lru_cache
from typing import Any

import numpy as np

from vlaprobe.configs.env import EnvConfig, SuiteName
from vlaprobe.envs.base import Observation
from vlaprobe.envs.bddl_scene import carried_object_goal, pick_place_goal, scene_from_problem, task_bddl
from vlaprobe.envs.libero_world import CAMERA, SceneIndex, drawer_fronts
from vlaprobe.envs.placements import (
    MAX_DRAWS,
    SAMPLED_INITS,
    PlacementReport,
    init_conditions_hold,
    layout_problems,
    placement_seed,
    read_layout,
    region_centers,
    swap_regions,
    swapped_samplers,
    table_center,
    table_placements,
)
from vlaprobe.envs.referents import parse_reference, placement_problems, reference_problems
from vlaprobe.envs.setup import _quiet_import_robosuite, prepare_libero
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols import Goal, Labeler, WorldState

NOOP_ACTION = np.array([0, 0, 0, 0, 0, 0, -1], dtype=np.float64)  # gripper open


@lru_cache(maxsize=4)
def _benchmark(suite: SuiteName) -> Any:
    prepare_libero(need_assets=False)  # task lists come from LIBERO's own files, not from the assets
    import contextlib
    import io

    from libero.libero import benchmark

    suites = benchmark.get_benchmark_dict()
    if suite not in suites:
        raise VlaprobeError(f"unknown LIBERO suite {suite!r}; use one of {sorted(suites)}")
    with contextlib.redirect_stdout(io.StringIO()):  # LIBERO prints "[info] using task orders ..." to stdout
        return suites[suite]()


def suite_tasks(suite: SuiteName = "libero_spatial") -> list[tuple[int, str]]:
    """(index, instruction) of every task of a suite; no simulator is built."""
    bench = _benchmark(suite)
    return [(i, bench.get_task(i).language) for i in range(bench.get_num_tasks())]


def num_init_states(suite: SuiteName, task: int) -> int:
    """How many fixed init states a task has (read from LIBERO's init-state file: no simulator)."""
    return len(_benchmark(suite).get_task_init_states(task))


def resolve_task(task: int | str, suite: SuiteName = "libero_spatial") -> int:
    """A task index from an index or an exact instruction (case-insensitive)."""
    tasks = suite_tasks(suite)
    if isinstance(task, str) and task.strip().lstrip("-").isdigit():
        task = int(task)
    if isinstance(task, int):
        if not 0 <= task < len(tasks):
            raise VlaprobeError(
                f"task index {task} out of range; {suite} has tasks 0-{len(tasks) - 1} (see `vlaprobe tasks`)"
            )
        return task
    for i, text in tasks:
        if text.lower() == task.strip().lower():
            return i
    raise VlaprobeError(f"no {suite} task has the instruction {task!r}; list them with `vlaprobe tasks`")


def task_problem(task: int, suite: SuiteName = "libero_spatial") -> dict[str, Any]:
    """LIBERO's parsed BDDL problem of one task (regions, objects, ``initial_state``); no simulator is built."""
    spec = _benchmark(suite).get_task(task)
    _quiet_import_robosuite()  # LIBERO's BDDL parser imports robosuite, which prints start-up advice
    from libero.libero import get_libero_path
    from libero.libero.envs.bddl_utils import robosuite_parse_problem

    return robosuite_parse_problem(
        os.path.join(get_libero_path("bddl_files"), spec.problem_folder, spec.bddl_file)
    )


class LiberoTaskEnv:
    """One LIBERO task: reset to a fixed init state (settled), step with the 7-D action, snapshot the world."""

    def __init__(self, task: int | str, cfg: EnvConfig | None = None) -> None:
        self.cfg = cfg or EnvConfig()
        assets = prepare_libero(self.cfg.assets, suite=self.cfg.suite)  # the suite's files, before any work
        assert assets is not None  # prepare_libero finds or refuses the assets folder
        from libero.libero import get_libero_path
        from libero.libero.envs import OffScreenRenderEnv

        bench = _benchmark(self.cfg.suite)
        self.task_index = resolve_task(task, self.cfg.suite)
        spec = bench.get_task(self.task_index)
        self.instruction: str = spec.language
        self.task_name: str = spec.name
        self._init_states = bench.get_task_init_states(self.task_index)
        self.sampled = self.cfg.inits != "fixed"
        self.num_init_states = SAMPLED_INITS if self.sampled else len(self._init_states)
        self.last_placement: PlacementReport | None = None
        """How the last sampled reset's layout was found (None under fixed inits)."""
        bddl = os.path.join(get_libero_path("bddl_files"), spec.problem_folder, spec.bddl_file)
        size = self.cfg.image_size
        self._env = OffScreenRenderEnv(
            bddl_file_name=bddl,
            camera_heights=size,
            camera_widths=size,
            camera_names=[CAMERA],
            has_offscreen_renderer=self.cfg.render,
            use_camera_obs=self.cfg.render,
            hard_reset=False,  # hard resets rebuild the simulation (1-3 s) and invalidate handles
        )
        self._sim_env = self._env.env
        problem = task_bddl(self.cfg.suite, self.task_index)
        self.scene = scene_from_problem(problem, assets)
        self.goal_conjunction = problem.goal
        """The task's BDDL goal, every conjunct (On, In, Open, Close, TurnOn, TurnOff)."""
        pick_place = pick_place_goal(problem.goal, self.scene)
        if pick_place is not None:  # absent otherwise: collection, the expert and the cognition need one
            self.goal: Goal = pick_place
        self.perturb_goal = carried_object_goal(problem.goal, self.scene)
        """What ``--perturb`` acts on (the perturbation path only; the labeler keeps ``pick_place``)."""
        self.labeler = Labeler(self.scene, pick_place)
        self._index = SceneIndex(self._sim_env, self.scene)
        self._reference = None
        if self.cfg.inits == "sampled-swap":
            self._reference = parse_reference(self.instruction, self.goal, self.scene)
            if self._reference is None:
                raise VlaprobeError(
                    f"--inits sampled-swap: task {self.task_index}'s instruction {self.instruction!r} has no form "
                    "whose referent can be checked after a swap; use --inits sampled"
                )
        self._gripper_command = -1.0
        self._step = 0
        model, data = self._sim_env.sim.model._model, self._sim_env.sim.data._data
        base = data.xpos[model.body(self._sim_env.robots[0].robot_model.root_body).id]
        self.robot_base = (float(base[0]), float(base[1]))
        """(x, y) of the robot's base (a mounted arm: fixed for the task)."""

    # ----- episode ----------------------------------------------------------------------------------------
    def reset(self, init: int) -> Observation:
        """Set the task's fixed init state ``init`` (or sampled layout ``init``), let objects settle, observe."""
        if not 0 <= init < self.num_init_states:
            kind = "sample index" if self.sampled else "init state"
            raise VlaprobeError(
                f"{kind} {init} out of range; task {self.task_index} has 0-{self.num_init_states - 1}"
            )
        if self.sampled:
            return self._reset_sampled(init)
        self._prepare_reset(1000 * self.task_index + init)
        self._env.reset()
        raw = self._env.set_init_state(self._init_states[init])
        return self._settle(raw)

    def _prepare_reset(self, seed: int) -> None:
        # Same init, same state: LIBERO's soft reset samples placements from numpy's global generator (then
        # overwritten by a fixed init state, but the draw shifts later randomness), and robosuite keeps the
        # gripper's last command and MuJoCo's solver warm start across resets.
        np.random.seed(seed)
        self._sim_env.robots[0].gripper.current_action[:] = 0
        self._index.mj_data.qacc_warmstart[:] = 0

    def _settle(self, raw: dict[str, Any]) -> Observation:
        self._gripper_command = -1.0
        # Only the last settle step's render is seen: the steps before it get a blank image instead (the physics
        # does not depend on rendering; the same images, byte for byte, ~0.1 s less per settle step).
        for i in range(self.cfg.settle_steps):
            with self._camera_off(self.cfg.render and i < self.cfg.settle_steps - 1):
                raw, _, _, _ = self._env.step(NOOP_ACTION)
        self._step = 0
        self.labeler.reset()  # a new episode: forget the last one's grasp and placing memory
        return self._observation(raw)

    @contextlib.contextmanager
    def _camera_off(self, off: bool) -> Iterator[None]:
        """Within: the agentview observable gets a blank image instead of a render. Its sampling clock runs on
        as before (it decides at which physics substep the next render happens; switching the observable off
        would stop the clock and shift every later image), so the renders after are byte for byte the same."""
        if not off:
            yield
            return
        observable = self._sim_env._observables[f"{CAMERA}_image"]
        render = observable._sensor  # robosuite 1.4's Observable: set_sensor() would render once to validate
        blank = np.zeros(observable._data_shape, dtype=np.uint8)

        def no_render(_cache: object) -> np.ndarray:
            return blank

        no_render.__modality__ = render.__modality__  # type: ignore[attr-defined]
        observable._sensor = no_render
        try:
            yield
        finally:
            observable._sensor = render

    def _unplace_fixtures(self) -> None:
        """Put the fixtures back at the origin before a sampling reset, as a freshly built scene has them:
        LIBERO's site-conditioned samplers (an object on a cabinet's top or in its drawer) add the fixture's
        sampled pose to the site's position, which they expect in the fixture's own frame. After a soft reset
        the site is already at its world position and those objects land ~1 m off (measured: every draw of
        task 3 placed the second bowl 1 m above the table and off the cabinet)."""
        model = self._sim_env.sim.model
        for fixture in self._sim_env.fixtures_dict.values():
            body = model.body_name2id(fixture.root_body)
            model.body_pos[body] = 0.0
            model.body_quat[body] = (1.0, 0.0, 0.0, 0.0)

    def _reset_sampled(self, init: int) -> Observation:
        """A new layout from LIBERO's placement sampler (reset without an init state), re-drawn until it passes
        the checks of :func:`~vlaprobe.envs.placements.layout_problems`."""
        from robosuite.utils.errors import RandomizationError

        problem, names = self._sim_env.parsed_problem, self.scene.tabletop
        rejected: list[str] = []
        for draw in range(MAX_DRAWS):
            seed = placement_seed(self.cfg.suite, self.task_index, self.cfg.layout_seed, init, draw)
            regions = self._swap(np.random.default_rng(seed)) if self._reference else None
            self._prepare_reset(seed)
            self._unplace_fixtures()
            try:
                with swapped_samplers(self._sim_env, regions):
                    raw = self._env.reset()
            except RandomizationError as exc:
                rejected.append(f"sampler: {exc}")
                continue
            sampled = self._index.mj_data.xquat[self._index.body_ids].copy()
            obs = self._settle(raw)
            layout = read_layout(
                self._sim_env, names, self._index.geom_owner, sampled, self._index.table_height
            )
            holds = init_conditions_hold(self._sim_env, problem)
            problems = layout_problems(layout, problem, holds, regions) + self._reference_problems()
            if not problems:
                moved = tuple((n, r) for n, r in (regions or {}).items() if r != table_placements(problem)[n])
                self.last_placement = PlacementReport(init, seed, draw + 1, tuple(rejected), moved)
                return obs
            rejected.append("; ".join(problems))
        raise VlaprobeError(
            f"task {self.task_index}: no valid sampled layout for sample {init} in {MAX_DRAWS} draws "
            f"(last: {rejected[-1]}); use --inits fixed for this task"
        )

    def _swap(self, rng: np.random.Generator) -> dict[str, str]:
        """A region permutation under which the instruction can still single out the object to pick, judged on
        the regions' centres before any physics (:func:`~vlaprobe.envs.referents.placement_problems`); the
        settled layout is checked again by :meth:`_reference_problems`."""
        problem, offset = self._sim_env.parsed_problem, self._sim_env.workspace_offset
        center = table_center(problem, offset)
        ref, goal, scene = self._reference, self.goal, self.scene
        assert ref is not None

        def plausible(swap: Mapping[str, str]) -> bool:
            xy = region_centers(problem, swap, offset)
            return not placement_problems(ref, goal, scene, xy, center)

        return swap_regions(problem, rng, plausible)

    def fixed_layout_problems(self, init: int) -> list[str]:
        """Reset to LIBERO's fixed init state ``init`` (as :meth:`reset` under ``--inits fixed``) and return what
        the sampled-layout checks would say of it: LIBERO ships these layouts, so every check must pass them
        (``bench/placement_checks.py``)."""
        self._prepare_reset(1000 * self.task_index + init)
        self._env.reset()
        raw = self._env.set_init_state(self._init_states[init])
        sampled = self._index.mj_data.xquat[self._index.body_ids].copy()
        self._settle(raw)
        e, names = self._sim_env, self.scene.tabletop
        layout = read_layout(e, names, self._index.geom_owner, sampled, self._index.table_height)
        return layout_problems(layout, e.parsed_problem, init_conditions_hold(e, e.parsed_problem))

    def _reference_problems(self) -> list[str]:
        """Under ``--inits sampled-swap``: why the instruction does not name the object to pick alone in the
        settled layout (:mod:`vlaprobe.envs.referents`); empty otherwise."""
        if self._reference is None:
            return []
        state = self.world_state()
        bits, _ = self.labeler(state)
        self.labeler.reset()  # the check must not leave memory in the labeler of the coming episode
        center = table_center(self._sim_env.parsed_problem, self._sim_env.workspace_offset)
        return reference_problems(
            self._reference, self.goal, self.scene, state, bits, self.labeler.vocabulary.object_atoms, center
        )

    def step(self, action: np.ndarray) -> Observation:
        """Apply a 7-D action (dx, dy, dz, droll, dpitch, dyaw, gripper: -1 open, +1 close)."""
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        if action.shape != (7,):
            raise VlaprobeError(
                f"action must have 7 values (dx,dy,dz,droll,dpitch,dyaw,gripper), got {action.shape}"
            )
        raw, _, _, _ = self._env.step(action)
        self._gripper_command = float(action[6])
        self._step += 1
        return self._observation(raw)

    def _observation(self, raw: dict[str, Any]) -> Observation:
        proprio = np.concatenate(
            [raw["robot0_eef_pos"], raw["robot0_eef_quat"], raw["robot0_gripper_qpos"]]
        ).astype(np.float32)
        image = raw.get(f"{CAMERA}_image") if self.cfg.render else None
        return Observation(
            image=image, proprio=proprio, step=self._step, success=bool(self._env.check_success())
        )

    def place_object(self, name: str, xy: tuple[float, float]) -> Observation:
        """Move the movable object ``name`` to (x, y), its bottom 3 mm above the table, at rest and with its
        orientation kept, then observe again (a new render): a perturbation between two steps."""
        e = self._sim_env
        if name not in self.scene.pickupable:
            raise VlaprobeError(f"cannot move {name!r}: not a movable object of task {self.task_index}")
        i = self.scene.tabletop.index(name)
        state = self.world_state()
        joint = e.get_object(name).joints[-1]
        qpos = np.array(e.sim.data.get_joint_qpos(joint), dtype=np.float64)
        qpos[0] += xy[0] - state.pos[i, 0]
        qpos[1] += xy[1] - state.pos[i, 1]
        qpos[2] += self._index.table_height + 0.003 - state.aabb_lo[i, 2]
        e.sim.data.set_joint_qpos(joint, qpos)
        e.sim.data.set_joint_qvel(joint, np.zeros(6))
        e.sim.forward()
        return self._observation(e._get_observations(force_update=True))

    def render(self) -> np.ndarray:
        """A fresh raw agentview render of the current state (same orientation as ``Observation.image``)."""
        size = self.cfg.image_size
        # robosuite's observations are sim.render's rows as they come (OpenGL order, bottom row first).
        return np.asarray(self._sim_env.sim.render(camera_name=CAMERA, width=size, height=size))

    def world_state(self) -> WorldState:
        """Snapshot the simulator into a :class:`WorldState` (what every detector reads)."""
        return self._index.world_state(self._gripper_command)

    def drawer_fronts(self) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        """Where each drawer of the scene opens and the hand pulls it (:func:`libero_world.drawer_fronts`)."""
        return drawer_fronts(self._sim_env, self.scene, self.world_state())

    def labels(self) -> tuple[np.ndarray, np.ndarray]:
        """(object bits, action bits) of the current state."""
        return self.labeler(self.world_state())

    # ----- LIBERO's own predicates (for checking our detectors) ----------------------------------------------
    def libero_predicate(self, name: str, *args: str) -> bool:
        """Evaluate one of LIBERO's own predicates (``On``, ``In``, ``Open``, ``TurnOn``) on the live state."""
        return bool(self._sim_env._eval_predicate([name.lower(), *args]))

    @property
    def sim_env(self) -> Any:
        """The underlying LIBERO/robosuite environment (privileged access, e.g. for the scripted expert)."""
        return self._sim_env

    def close(self) -> None:
        self._env.close()

    def __enter__(self) -> LiberoTaskEnv:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
