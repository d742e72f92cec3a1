"""LIBERO task environments: fixed init states, settled resets, raw agentview images, world-state snapshots.

One :class:`LiberoTaskEnv` wraps one LIBERO task (an ``OffScreenRenderEnv``). The typed scene (which objects
are pickupable, which fixture regions are drawers, which fixtures switch on) is read from the task's BDDL
problem and the built scene, not from a hand-typed list, so other LIBERO suites need no new detectors.
"""

from __future__ import annotations

import os
from functools import lru_cache
from typing import Any

import numpy as np

from vlaprobe.configs.env import EnvConfig
from vlaprobe.envs.base import Observation
from vlaprobe.envs.placements import (
    MAX_DRAWS,
    SAMPLED_INITS,
    PlacementReport,
    init_conditions_hold,
    layout_problems,
    placement_seed,
    read_layout,
)
from vlaprobe.envs.setup import _quiet_import_robosuite, prepare_libero
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols import Articulation, Goal, Labeler, Scene, WorldState
from vlaprobe.symbols.world import FINGER_GAP_MAX

CAMERA = "agentview"
NOOP_ACTION = np.array([0, 0, 0, 0, 0, 0, -1], dtype=np.float64)  # gripper open


@lru_cache(maxsize=4)
def _benchmark(suite: str) -> Any:
    prepare_libero(need_assets=False)  # task lists come from LIBERO's own files, not from the assets
    import contextlib
    import io

    from libero.libero import benchmark

    suites = benchmark.get_benchmark_dict()
    if suite not in suites:
        raise VlaprobeError(f"unknown LIBERO suite {suite!r}; use one of {sorted(suites)}")
    with contextlib.redirect_stdout(io.StringIO()):  # LIBERO prints "[info] using task orders ..." to stdout
        return suites[suite]()


def suite_tasks(suite: str = "libero_spatial") -> list[tuple[int, str]]:
    """(index, instruction) of every task of a suite; no simulator is built."""
    bench = _benchmark(suite)
    return [(i, bench.get_task(i).language) for i in range(bench.get_num_tasks())]


def num_init_states(suite: str, task: int) -> int:
    """How many fixed init states a task has (read from LIBERO's init-state file: no simulator)."""
    return len(_benchmark(suite).get_task_init_states(task))


def resolve_task(task: int | str, suite: str = "libero_spatial") -> int:
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


def task_problem(task: int, suite: str = "libero_spatial") -> dict[str, Any]:
    """LIBERO's parsed BDDL problem of one task (regions, objects, ``initial_state``); no simulator is built."""
    spec = _benchmark(suite).get_task(task)
    _quiet_import_robosuite()  # LIBERO's BDDL parser imports robosuite, which prints start-up advice
    from libero.libero import get_libero_path
    from libero.libero.envs.bddl_utils import robosuite_parse_problem

    return robosuite_parse_problem(
        os.path.join(get_libero_path("bddl_files"), spec.problem_folder, spec.bddl_file)
    )


def _articulation(props: dict[str, Any], key: str) -> Articulation:
    """LIBERO's open/turn-on rule from an articulated object's declared ranges."""
    art = props.get("articulation", {})
    if key == "open":
        open_r, close_r = art.get("default_open_ranges", []), art.get("default_close_ranges", [])
        if not open_r:
            raise VlaprobeError(
                "a container's fixture declares no open range; this LIBERO object is not supported"
            )
        # Cabinets open as the joint goes negative (open range below the closed one), microwaves the other way.
        if close_r and max(open_r) <= min(close_r):
            return Articulation(threshold=float(max(open_r)), below=True)
        return Articulation(threshold=float(min(open_r)), below=False)
    on_r = art.get("default_turnon_ranges", [])
    return Articulation(threshold=float(min(on_r)), below=False)


class LiberoTaskEnv:
    """One LIBERO task: reset to a fixed init state (settled), step with the 7-D action, snapshot the world."""

    def __init__(self, task: int | str, cfg: EnvConfig | None = None) -> None:
        self.cfg = cfg or EnvConfig()
        prepare_libero(self.cfg.assets)
        from libero.libero import get_libero_path
        from libero.libero.envs import OffScreenRenderEnv

        bench = _benchmark(self.cfg.suite)
        self.task_index = resolve_task(task, self.cfg.suite)
        spec = bench.get_task(self.task_index)
        self.instruction: str = spec.language
        self.task_name: str = spec.name
        self._init_states = bench.get_task_init_states(self.task_index)
        self.sampled = self.cfg.inits == "sampled"
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
        self.scene = self._read_scene()
        self.goal = self._read_goal()
        self.labeler = Labeler(self.scene, self.goal)
        self._index_geoms()
        self._gripper_command = -1.0
        self._step = 0

    # ----- scene, read once -----------------------------------------------------------------------------
    def _read_scene(self) -> Scene:
        e = self._sim_env
        problem = e.parsed_problem
        pickupable = tuple(n for names in problem["objects"].values() for n in names)
        fixtures = tuple(n for kind, names in problem["fixtures"].items() if kind != "table" for n in names)
        containers: list[str] = []
        arts: list[Articulation] = []
        surfaces: list[str] = []
        parents: dict[str, str] = {}
        for name, site in e.object_sites_dict.items():
            parent = getattr(site, "parent_name", None)
            if parent not in fixtures:
                continue  # table zones are placement aids, not objects
            parents[name] = parent
            if site.joints:
                containers.append(name)
                arts.append(_articulation(e.get_object(parent).object_properties, "open"))
            else:
                surfaces.append(name)
        on_off = tuple(f for f in fixtures if hasattr(e.get_object(f), "turn_on"))
        return Scene(
            pickupable=pickupable,
            fixtures=fixtures,
            containers=tuple(containers),
            container_articulation=tuple(arts),
            surfaces=tuple(surfaces),
            on_off=on_off,
            on_off_articulation=tuple(_articulation(e.get_object(k).object_properties, "on") for k in on_off),
            region_parent=parents,
        )

    def _read_goal(self) -> Goal:
        goal = self._sim_env.parsed_problem["goal_state"]
        if len(goal) != 1 or goal[0][0].lower() != "on":
            raise VlaprobeError(
                f"task goal {goal} is not a single On(a, b); only pick-and-place goals are supported"
            )
        return Goal(pick=goal[0][1], place=goal[0][2])

    def _index_geoms(self) -> None:
        """Map every collision geom to a row of WorldState.contact; precompute joint and site addresses."""
        e = self._sim_env
        model = e.sim.model
        names = self.scene.tabletop
        n = len(names)
        owner = np.full(model.ngeom, -1, dtype=np.int64)
        for i, name in enumerate(names):
            for g in e.get_object(name).contact_geoms:
                owner[model.geom_name2id(g)] = i
        table = [g for g in range(model.ngeom) if (model.geom_id2name(g) or "") == "table_collision"]
        owner[table] = n
        self._table_height = (
            float(e.sim.data.geom_xpos[table[0]][2] + model.geom_size[table[0]][2]) if table else 0.0
        )
        fingers = e.robots[0].gripper.important_geoms
        for offset, key in ((1, "left_finger"), (2, "right_finger")):
            for g in fingers[key]:
                owner[model.geom_name2id(g)] = n + offset
        # Geom pairs whose distances give WorldState.finger_gap: (finger geom, object geom) per finger and object.
        self._finger_pairs = [
            [
                [
                    (model.geom_name2id(f), model.geom_name2id(g))
                    for f in fingers[key]
                    for g in e.get_object(name).contact_geoms
                ]
                for key in ("left_finger", "right_finger")
            ]
            for name in self.scene.pickupable
        ]
        self._geom_owner = owner
        obj_geoms = np.flatnonzero((owner >= 0) & (owner < n))
        self._aabb_geoms = obj_geoms
        self._aabb_owner = owner[obj_geoms]
        self._body_ids = np.array([e.obj_body_id[name] for name in names])
        self._site_ids = np.array([model.site_name2id(r) for r in self.scene.regions], dtype=np.int64)
        self._region_size = np.array(
            [np.asarray(e.object_sites_dict[r].size, dtype=np.float64) for r in self.scene.regions]
        ).reshape(-1, 3)

        def qpos_addr(joint: str) -> int:
            return int(model.get_joint_qpos_addr(joint))

        self._container_qpos = np.array(
            [qpos_addr(e.object_sites_dict[c].joints[0]) for c in self.scene.containers], dtype=np.int64
        )
        self._on_off_qpos = np.array(
            [qpos_addr(e.get_object(k).joints[0]) for k in self.scene.on_off], dtype=np.int64
        )
        self._cam_id = model.camera_name2id(CAMERA)
        self._mj_model = model._model
        self._mj_data = e.sim.data._data

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
        self._mj_data.qacc_warmstart[:] = 0

    def _settle(self, raw: dict[str, Any]) -> Observation:
        self._gripper_command = -1.0
        for _ in range(self.cfg.settle_steps):
            raw, _, _, _ = self._env.step(NOOP_ACTION)
        self._step = 0
        self.labeler.reset()  # a new episode: forget the last one's grasp and placing memory
        return self._observation(raw)

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
            seed = placement_seed(self.task_index, init, draw)
            self._prepare_reset(seed)
            self._unplace_fixtures()
            try:
                raw = self._env.reset()
            except RandomizationError as exc:
                rejected.append(f"sampler: {exc}")
                continue
            sampled = self._mj_data.xquat[self._body_ids].copy()
            obs = self._settle(raw)
            layout = read_layout(self._sim_env, names, self._geom_owner, sampled, self._table_height)
            problems = layout_problems(layout, problem, init_conditions_hold(self._sim_env, problem))
            if not problems:
                self.last_placement = PlacementReport(init, seed, draw + 1, tuple(rejected))
                return obs
            rejected.append("; ".join(problems))
        raise VlaprobeError(
            f"task {self.task_index}: no valid sampled layout for sample {init} in {MAX_DRAWS} draws "
            f"(last: {rejected[-1]}); use --inits fixed for this task"
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
        qpos[2] += self._table_height + 0.003 - state.aabb_lo[i, 2]
        e.sim.data.set_joint_qpos(joint, qpos)
        e.sim.data.set_joint_qvel(joint, np.zeros(6))
        e.sim.forward()
        return self._observation(e._get_observations(force_update=True))

    def render(self) -> np.ndarray:
        """A fresh raw agentview render of the current state (same orientation as ``Observation.image``)."""
        size = self.cfg.image_size
        # robosuite's observations are sim.render's rows as they come (OpenGL order, bottom row first).
        return np.asarray(self._sim_env.sim.render(camera_name=CAMERA, width=size, height=size))

    # ----- world state ------------------------------------------------------------------------------------
    def world_state(self) -> WorldState:
        """Snapshot the simulator into a :class:`WorldState` (what every detector reads)."""
        import mujoco  # not at module level: mujoco picks its GL backend at import (see envs.setup)

        data = self._mj_data
        model = self._mj_model
        n = len(self.scene.tabletop)
        # World AABB of each collision geom (box of its local AABB, rotated), reduced per object.
        g = self._aabb_geoms
        aabb = model.geom_aabb[g]  # (G, 6): local centre, half sizes
        rot = data.geom_xmat[g].reshape(-1, 3, 3)
        centre = data.geom_xpos[g] + np.einsum("gij,gj->gi", rot, aabb[:, :3])
        half = np.einsum("gij,gj->gi", np.abs(rot), aabb[:, 3:])
        lo = np.full((n, 3), np.inf)
        hi = np.full((n, 3), -np.inf)
        np.minimum.at(lo, self._aabb_owner, centre - half)
        np.maximum.at(hi, self._aabb_owner, centre + half)
        # Contacts between entities (objects, table, fingers).
        contact = np.zeros((n + 3, n + 3), dtype=bool)
        ncon = data.ncon
        if ncon:
            a = self._geom_owner[data.contact.geom1[:ncon]]
            b = self._geom_owner[data.contact.geom2[:ncon]]
            keep = (a >= 0) & (b >= 0) & (a != b)
            contact[a[keep], b[keep]] = True
            contact[b[keep], a[keep]] = True
        sites = self._site_ids
        robot = self._sim_env.robots[0]
        # Body velocities (angular, then linear) at each object's origin, world frame.
        vel = np.zeros((n, 6))
        for i, body in enumerate(self._body_ids):
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, int(body), vel[i], 0)
        return WorldState(
            pos=data.xpos[self._body_ids].copy(),
            aabb_lo=lo,
            aabb_hi=hi,
            contact=contact,
            region_pos=data.site_xpos[sites].copy(),
            region_mat=data.site_xmat[sites].reshape(-1, 3, 3).copy(),
            region_size=self._region_size,
            container_qpos=data.qpos[self._container_qpos].copy(),
            on_off_qpos=data.qpos[self._on_off_qpos].copy(),
            camera_pos=data.cam_xpos[self._cam_id].copy(),
            camera_mat=data.cam_xmat[self._cam_id].reshape(3, 3).copy(),
            camera_fovy=float(model.cam_fovy[self._cam_id]),
            eef_pos=np.array(self._sim_env.sim.data.site_xpos[robot.eef_site_id]),
            gripper_qpos=data.qpos[robot._ref_gripper_joint_pos_indexes].copy(),
            gripper_qvel=data.qvel[robot._ref_gripper_joint_vel_indexes].copy(),
            finger_gap=self._finger_gap(),
            gripper_command=self._gripper_command,
            lin_vel=vel[:, 3:],
            ang_vel=vel[:, :3],
            table_height=self._table_height,
        )

    def _finger_gap(self) -> np.ndarray:
        """(P, 2) distance of each finger to each pickupable object, capped at ``FINGER_GAP_MAX``.

        MuJoCo culls far geom pairs by their bounding spheres (returning 1e10): ~0.3 ms for all pairs.
        """
        import mujoco

        model, data, fromto = self._mj_model, self._mj_data, np.zeros(6)

        def distance(pairs: list[tuple[int, int]]) -> float:
            return min(mujoco.mj_geomDistance(model, data, f, g, FINGER_GAP_MAX, fromto) for f, g in pairs)

        gap = np.array([[distance(pairs) for pairs in per_finger] for per_finger in self._finger_pairs])
        return np.minimum(gap.reshape(-1, 2), FINGER_GAP_MAX)

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
