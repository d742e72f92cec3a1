"""Skill: push an object out of the way of a drawer before the drawer opens over it.

LIBERO-goal's "open the top drawer and put the bowl inside" starts with the bowl half under where the top
drawer comes to lie once open (10 cm above the rim): with the drawer open, the hand (12 cm tall over the grip
point, 20 cm along the finger axis) meets the drawer at every side of the rim. So before the drawer opens,
this skill reads the box the drawer will take (:meth:`~vlaprobe.experts.drawer.Drawer.opened_box`) and, when
the object's box comes within ``CLEAR_GAP`` of it, pushes the object along the table (the
:class:`~vlaprobe.experts.push.Push` skill, towards a spot) the shortest way out: sideways or away from the
cabinet, never into it, to a spot ``CLEAR_NEIGHBOUR`` clear of every other object's box (the direction that
keeps the most room when none is). An object already clear ends the skill at once.
"""

from __future__ import annotations

import numpy as np

from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts.drawer import Drawer
from vlaprobe.experts.geometry import CLEAR_GAP, CLEAR_NEIGHBOUR, CLEAR_SIDESTEP, CLEAR_TOL
from vlaprobe.experts.push import Push
from vlaprobe.experts.targets import Target
from vlaprobe.symbols import WorldState

JUMP = 0.05
"""Metres the object moves between two steps for the skill to aim again (a displacement, not a push)."""


def clear_move(
    lo: np.ndarray, hi: np.ndarray, subject: int, box: tuple[np.ndarray, np.ndarray], into: np.ndarray
) -> np.ndarray | None:
    """How far to push object ``subject`` (rows of the scene's boxes ``lo``, ``hi``, (N, 3)) so that its box
    stands ``CLEAR_GAP`` outside ``box`` (the opened drawer's corners) along one world axis, not along ``into``
    (the way into the cabinet), shifted by up to ``CLEAR_SIDESTEP`` along the other axis; None when it is
    clear already. Among the moves that keep it ``CLEAR_NEIGHBOUR`` off the other objects' boxes the shortest
    wins, else the roomiest."""
    box_lo, box_hi = box[0] - CLEAR_GAP, box[1] + CLEAR_GAP
    own_lo, own_hi = lo[subject], hi[subject]
    radius = 0.5 * float(np.max(own_hi[:2] - own_lo[:2]))
    others = np.arange(len(lo)) != subject
    candidates = []
    for axis in (0, 1):
        for sign in (1.0, -1.0):
            shift = box_hi[axis] - own_lo[axis] if sign > 0 else own_hi[axis] - box_lo[axis]
            if shift <= 0.0:
                return None  # already outside the box along this axis
            if sign * into[axis] > 0.5:
                continue
            for side in np.linspace(-CLEAR_SIDESTEP, CLEAR_SIDESTEP, 7):
                move = np.zeros(3)
                move[axis], move[1 - axis] = sign * shift, side
                centre = 0.5 * (own_lo[:2] + own_hi[:2]) + move[:2]
                outside = np.maximum(np.maximum(lo[others, :2] - centre, centre - hi[others, :2]), 0.0)
                room = float(np.linalg.norm(outside, axis=1).min(initial=np.inf)) - radius
                crowded = room < CLEAR_NEIGHBOUR
                candidates.append((crowded, -room if crowded else float(np.linalg.norm(move)), move))
    return min(candidates, key=lambda c: (c[0], c[1]))[2]


class Clear(Push):
    """Push ``subject`` out of the way of the drawer whose region is ``region`` (module doc)."""

    def __init__(self, env: LiberoTaskEnv, subject: str, region: str, seed: int = 0) -> None:
        self._drawer = Drawer(env, region, opening=True, seed=seed)
        super().__init__(env, subject, Target(f"clear {region}"), seed)

    def reset(self) -> None:
        super().reset()
        self._home = self._eef()[0]
        self._drawer.reset()  # the drawer's pose after this episode's reset
        state = self.env.world_state()
        self._last = state.pos[self._subject].copy()
        if not self._aim(state):
            self._enter("done")

    def _aim(self, state: WorldState) -> bool:
        """Aim the push at the nearest spot clear of the opened drawer; False when the object is clear."""
        move = clear_move(
            state.aabb_lo, state.aabb_hi, self._subject, self._drawer.opened_box(), -self._drawer.out
        )
        if move is None:
            return False
        spot = state.pos[self._subject] + move
        at = (float(spot[0]), float(spot[1]), float(spot[2]))
        self._target = Target(self._target.name, half=(CLEAR_TOL, CLEAR_TOL, 0.0), at=at)
        return True

    def _decide(self, state: WorldState) -> np.ndarray:
        """A jump of the object (``--perturb``'s displacement; no push moves it ``JUMP`` in a step): aim again
        from where it landed, or retreat when it landed clear of the drawer."""
        obj = state.pos[self._subject]
        jumped = float(np.linalg.norm(obj[:2] - self._last[:2])) > JUMP
        self._last = obj.copy()
        if jumped and self.phase not in ("retreat", "done"):
            if self._aim(state):
                self._enter("approach")
            else:
                self._anchor = self._retreat_point(self._eef()[0])
                self._enter("retreat")
        return super()._decide(state)

    def _retreat_point(self, pos: np.ndarray) -> np.ndarray:
        """Back to where the skill started (high, away from the drawer: the drawer skill returns there too)."""
        return self._home

    def _retreat(self, pos: np.ndarray, command: float) -> np.ndarray | None:
        if pos[2] < self._home[2] - 0.03:  # straight up first, clear of what stands around
            return self._action(np.append(pos[:2], self._home[2]), command)
        return super()._retreat(pos, command)
