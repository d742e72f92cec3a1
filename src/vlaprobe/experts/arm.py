"""Where the arm's links will be when the grip point reaches a planned pose: inverse kinematics on a scratch copy
of the simulator's state, never stepping the live one.

The controller (robosuite's OSC_POSE) reaches a pose with the arm's redundancy pulled towards the joint
configuration it was reset with (its null-space torque); the prediction does the same: damped least squares on
the grip site's position and rotation, plus a null-space step towards that configuration. A grasp side whose
gripper is free can still put the forearm into a drawer's front above the object (LIBERO-90 task 29):
:meth:`ArmModel.clearance` measures how near the links come to obstacles there, for the side choice.
"""

from __future__ import annotations

import numpy as np

from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts.geometry import _rotvec

IK_ITERATIONS = 40  # damped least-squares steps per prediction
IK_DAMPING = 1e-3  # damping of the least-squares solve (squared metres)
IK_TOL = 2e-4  # stop once the pose error (metres, radians) is below this
NULL_GAIN = 0.5  # share of the way towards the rest configuration taken per step, in the null space
ARM_FIRST_JOINT = (
    3  # the links moved by the 4th joint on (elbow, forearm, wrist) can reach what the hand passes
)


class ArmModel:
    """The robot arm of ``env``: predicts its links' collision boxes for a grip-site pose (module doc)."""

    def __init__(self, env: LiberoTaskEnv, eef_site: int, gripper_geoms: np.ndarray) -> None:
        import mujoco  # here, not at the top: MuJoCo picks its GL backend on import (envs/setup.py picks first)

        robot = env.sim_env.robots[0]
        self._model = env.sim_env.sim.model._model
        self._live = env.sim_env.sim.data._data
        self._scratch = mujoco.MjData(self._model)
        self._site = eef_site
        self._controller = robot.controller
        joints = [self._model.joint(j) for j in robot.robot_joints]
        self._qpos = np.array([int(j.qposadr[0]) for j in joints])
        self._dofs = np.array([int(j.dofadr[0]) for j in joints])
        moved = {int(j.bodyid[0]) for j in joints[ARM_FIRST_JOINT:]}
        bodies = self._model.geom_bodyid
        collides = (self._model.geom_contype != 0) | (self._model.geom_conaffinity != 0)
        self.geoms = np.array(
            [
                g
                for g in np.flatnonzero(collides)
                if self._in_subtree(int(bodies[g]), moved) and g not in set(gripper_geoms.tolist())
            ],
            dtype=int,
        )

    def _in_subtree(self, body: int, roots: set[int]) -> bool:
        while body > 0:
            if body in roots:
                return True
            body = int(self._model.body_parentid[body])
        return False

    def solve(self, pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """The arm's joint positions that put the grip site at ``pos`` with rotation ``rot`` (from the live
        configuration); the scratch state is left in that configuration."""
        import mujoco

        model, data = self._model, self._scratch
        data.qpos[:] = self._live.qpos
        rest = np.asarray(getattr(self._controller, "initial_joint", data.qpos[self._qpos]), dtype=float)
        jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        for _ in range(IK_ITERATIONS):
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            error = np.concatenate(
                [pos - data.site_xpos[self._site], _rotvec(rot @ data.site_xmat[self._site].reshape(3, 3).T)]
            )
            if np.abs(error).max() < IK_TOL:
                break
            mujoco.mj_jacSite(model, data, jacp, jacr, self._site)
            jac = np.vstack([jacp, jacr])[:, self._dofs]
            inverse = jac.T @ np.linalg.inv(jac @ jac.T + IK_DAMPING * np.eye(6))
            q = data.qpos[self._qpos]
            null = (np.eye(len(q)) - inverse @ jac) @ (NULL_GAIN * (rest - q))
            q = q + inverse @ error + null
            low, high = self._model.jnt_range[self._model.dof_jntid[self._dofs]].T
            data.qpos[self._qpos] = np.clip(q, low, high)
        mujoco.mj_kinematics(model, data)
        return data.qpos[self._qpos].copy()

    def clearance(self, pos: np.ndarray, rot: np.ndarray, obstacles: np.ndarray, limit: float) -> float:
        """Least signed distance (metres, capped at ``limit``) between the links' collision geoms and the
        ``obstacles`` geoms with the grip site at ``pos``, ``rot``: MuJoCo's own distance (meshes by their
        convex hulls; a box around a forearm's mesh would touch a drawer's front at every grasp side)."""
        import mujoco

        self.solve(pos, rot)
        model, data = self._model, self._scratch
        best = limit
        for g in self.geoms:
            reach = model.geom_rbound[g] + model.geom_rbound[obstacles] + limit
            near = obstacles[np.linalg.norm(data.geom_xpos[obstacles] - data.geom_xpos[g], axis=1) < reach]
            for o in near:
                best = min(best, mujoco.mj_geomDistance(model, data, int(g), int(o), limit, None))
        return float(best)
