"""Where a built LIBERO scene stands: world-state snapshots.

The typed scene and goal are read from the task's BDDL file (:mod:`vlaprobe.envs.bddl_scene`), not from the
simulator. :class:`SceneIndex` maps the simulator's geoms, sites and joints to the scene's rows once, then
snapshots the simulator into the :class:`~vlaprobe.symbols.WorldState` every detector reads.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vlaprobe.symbols import Scene, WorldState
from vlaprobe.symbols.world import FINGER_GAP_MAX

CAMERA = "agentview"


def workspace_geoms(e: Any) -> tuple[list[int], float]:
    """The collision geoms of the workspace body (the floor, the study or living-room table: the body named by
    LIBERO's ``workspace_name``) and the height of their top: the floor plane's height, else the highest top of
    the geoms' world boxes. (0.0 when the scene has none.)"""
    import mujoco

    model = e.sim.model
    raw = model._model
    root = model.body_name2id(e.workspace_name) if e.workspace_name in model.body_names else -1
    geoms = [
        g
        for g in range(model.ngeom)
        if root >= 0
        and model.body_rootid[model.geom_bodyid[g]] == root
        and (model.geom_contype[g] or model.geom_conaffinity[g])
    ]
    if not geoms:
        return [], 0.0
    data = e.sim.data
    tops = []
    for g in geoms:
        if raw.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
            tops.append(float(data.geom_xpos[g][2]))
            continue
        aabb = raw.geom_aabb[g]
        rot = np.asarray(data.geom_xmat[g]).reshape(3, 3)
        centre = np.asarray(data.geom_xpos[g]) + rot @ aabb[:3]
        tops.append(float(centre[2] + np.abs(rot)[2] @ aabb[3:]))
    return geoms, max(tops)


class SceneIndex:
    """Geom, site and joint addresses of one built scene, and the world-state snapshot read through them."""

    def __init__(self, e: Any, scene: Scene) -> None:
        """Map every collision geom to a row of WorldState.contact; precompute joint and site addresses."""
        self.scene = scene
        model = e.sim.model
        names = scene.tabletop
        n = len(names)
        owner = np.full(model.ngeom, -1, dtype=np.int64)
        for i, name in enumerate(names):
            for g in e.get_object(name).contact_geoms:
                owner[model.geom_name2id(g)] = i
        table = [g for g in range(model.ngeom) if (model.geom_id2name(g) or "") == "table_collision"]
        if table:  # the tabletop and kitchen scenes: the table's collision box
            self.table_height = float(e.sim.data.geom_xpos[table[0]][2] + model.geom_size[table[0]][2])
        else:
            table, self.table_height = workspace_geoms(e)
        owner[table] = n
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
            for name in scene.pickupable
        ]
        self.geom_owner = owner
        obj_geoms = np.flatnonzero((owner >= 0) & (owner < n))
        self._aabb_geoms = obj_geoms
        self._aabb_owner = owner[obj_geoms]
        self.body_ids = np.array([e.obj_body_id[name] for name in names])
        self._site_ids = np.array([model.site_name2id(r) for r in scene.regions], dtype=np.int64)
        self._region_size = np.array(
            [np.asarray(e.object_sites_dict[r].size, dtype=np.float64) for r in scene.regions]
        ).reshape(-1, 3)

        def qpos_addr(joint: str) -> int:
            return int(model.get_joint_qpos_addr(joint))

        self._container_qpos = np.array(
            [qpos_addr(e.object_sites_dict[c].joints[0]) for c in scene.containers]
            + [qpos_addr(e.get_object(d).joints[0]) for d in scene.doors],
            dtype=np.int64,
        )
        self._on_off_qpos = np.array(
            [qpos_addr(e.get_object(k).joints[0]) for k in scene.on_off], dtype=np.int64
        )
        self._cam_id = model.camera_name2id(CAMERA)
        self.mj_model = model._model
        self.mj_data = e.sim.data._data
        self._robot = e.robots[0]
        self._sim = e.sim

    def world_state(self, gripper_command: float) -> WorldState:
        """Snapshot the simulator into a :class:`WorldState` (what every detector reads)."""
        import mujoco  # not at module level: mujoco picks its GL backend at import (see envs.setup)

        data = self.mj_data
        model = self.mj_model
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
            a = self.geom_owner[data.contact.geom1[:ncon]]
            b = self.geom_owner[data.contact.geom2[:ncon]]
            keep = (a >= 0) & (b >= 0) & (a != b)
            contact[a[keep], b[keep]] = True
            contact[b[keep], a[keep]] = True
        sites = self._site_ids
        robot = self._robot
        # Body velocities (angular, then linear) at each object's origin, world frame.
        vel = np.zeros((n, 6))
        for i, body in enumerate(self.body_ids):
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, int(body), vel[i], 0)
        return WorldState(
            pos=data.xpos[self.body_ids].copy(),
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
            eef_pos=np.array(self._sim.data.site_xpos[robot.eef_site_id]),
            gripper_qpos=data.qpos[robot._ref_gripper_joint_pos_indexes].copy(),
            gripper_qvel=data.qvel[robot._ref_gripper_joint_vel_indexes].copy(),
            finger_gap=self._finger_gap(),
            gripper_command=gripper_command,
            lin_vel=vel[:, 3:],
            ang_vel=vel[:, :3],
            table_height=self.table_height,
        )

    def _finger_gap(self) -> np.ndarray:
        """(P, 2) distance of each finger to each pickupable object, capped at ``FINGER_GAP_MAX``.

        MuJoCo culls far geom pairs by their bounding spheres (returning 1e10): ~0.3 ms for all pairs.
        """
        import mujoco

        model, data, fromto = self.mj_model, self.mj_data, np.zeros(6)

        def distance(pairs: list[tuple[int, int]]) -> float:
            return min(mujoco.mj_geomDistance(model, data, f, g, FINGER_GAP_MAX, fromto) for f, g in pairs)

        gap = np.array([[distance(pairs) for pairs in per_finger] for per_finger in self._finger_pairs])
        return np.minimum(gap.reshape(-1, 2), FINGER_GAP_MAX)


HAND_MARGIN = 0.10
"""Metres a drawer's way reaches beyond its open front: the hand that grasps its handle and pulls."""


def drawer_fronts(e: Any, scene: Scene, world: WorldState) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """The (x, y) low and high corners of each drawer's way in the built scene ``e``: its cabinet's footprint
    with every drawer shut, swept along the drawers' opening direction (the world-frame slide axis, towards its
    range's open end) by their travel plus :data:`HAND_MARGIN`. One box per cabinet, whatever its drawers' state:
    ``world``'s box of the cabinet holds its drawers as they are, so it is swept by what is left of the travel of
    the drawer opened farthest (swept by the whole travel again, an open drawer's way covered the table's width)."""
    model, data = e.sim.model, e.sim.data
    boxes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for cabinet in dict.fromkeys(scene.region_parent.get(r, "") for r in scene.containers):
        if cabinet not in scene.tabletop:
            continue
        joints = [
            model.joint_name2id(e.object_sites_dict[r].joints[0])
            for r in scene.containers
            if scene.region_parent.get(r) == cabinet
        ]
        axis = np.asarray(data.xmat[model.jnt_bodyid[joints[0]]]).reshape(3, 3) @ np.asarray(
            model.jnt_axis[joints[0]]
        )
        low, high = (float(v) for v in model.jnt_range[joints[0]])
        end = low if abs(low) >= abs(high) else high  # the open end: LIBERO's drawers open towards -0.16
        opened = max(float(data.qpos[model.jnt_qposadr[j]]) * np.sign(end) for j in joints)
        left = max(abs(end) - max(opened, 0.0), 0.0)
        sweep = np.sign(end) * axis[:2] * (left + HAND_MARGIN)
        i = scene.tabletop.index(cabinet)
        lo, hi = world.aabb_lo[i, :2], world.aabb_hi[i, :2]
        boxes[cabinet] = (np.minimum(lo, lo + sweep), np.maximum(hi, hi + sweep))
    return tuple(boxes.values())
