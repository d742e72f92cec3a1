"""Skill: push a flat object (a plate) along the table until its origin is inside a placement region.

``approach``: over the point ``PUSH_BEHIND`` behind the object's edge on the far side from the region, or
``PUSH_INSET`` inside it when something stands there (the fingers then push the rim from the inside: a hand
behind the plate would meet the cabinet's handles), at the travel height, fingers across the push direction; ``descend`` to ``PUSH_HEIGHT`` above the table (closed
fingers); ``push`` towards the region's centre, steering by the object's own position, until its origin lies in
the inner ``PUSH_INSIDE`` share of the region; then ``retreat`` up (``done``). When the object drifts more than
``PUSH_DRIFT`` off the push line or stops coming nearer (it rides over the fingers, or pushes a neighbour), the
skill rises and approaches again from behind where it now is.
"""

from __future__ import annotations

import numpy as np

from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.experts.base import ArmSkill
from vlaprobe.experts.geometry import (
    CLEAR_MARGIN,
    CLOSE,
    PHASE_STEPS,
    POS_TOL,
    PUSH_BEHIND,
    PUSH_BLOCKED,
    PUSH_CLEARANCE,
    PUSH_DEEPER,
    PUSH_DRIFT,
    PUSH_HEIGHT,
    PUSH_INSET,
    PUSH_INSIDE,
    PUSH_OVER,
    PUSH_STEP,
    RETREAT_HEIGHT,
    STALL_STEPS,
)
from vlaprobe.experts.targets import Target
from vlaprobe.symbols.world import WorldState


class Push(ArmSkill):
    """Push ``subject`` into the region ``place`` (module doc)."""

    def __init__(self, env: LiberoTaskEnv, subject: str, place: Target, seed: int = 0) -> None:
        super().__init__(env, seed, avoid=subject)
        self._subject = env.scene.tabletop.index(subject)
        self._target = place
        self.reset()

    def reset(self) -> None:
        super().reset()
        self._direction: np.ndarray = np.zeros(3)
        self._deeper = 0.0  # how much deeper inside the rim a push starts after blocked descents
        self._enter("approach")

    def _enter(self, phase: str) -> None:
        super()._enter(phase)
        if phase == "approach":  # a push the object resisted winds the integral up: the next approach stalls
            self._integral = np.zeros(3)  # 3 cm short of its start (LIBERO-goal task 5, init 1)

    def _inside(self, state: WorldState) -> bool:
        offset = np.abs(state.pos[self._subject] - self._target.point(state, self._data))[:2]
        return bool(np.all(offset < PUSH_INSIDE * np.asarray(self._target.half)[:2]))

    def _start(self, state: WorldState) -> np.ndarray:
        """Where the fingers start pushing: behind the object's edge, opposite the region."""
        obj = state.pos[self._subject]
        goal = self._target.point(state, self._data)
        direction = np.append(goal[:2] - obj[:2], 0.0)
        self._direction = direction / max(float(np.linalg.norm(direction)), 1e-9)
        lo, hi = state.aabb_lo[self._subject], state.aabb_hi[self._subject]
        radius = 0.5 * float(np.max(hi[:2] - lo[:2]))
        start = obj - (radius + PUSH_BEHIND) * self._direction
        behind = self._corridor_top(start, start, PUSH_CLEARANCE)
        start[2] = lo[2] + PUSH_HEIGHT
        if behind > lo[2] + PUSH_CLEARANCE or self._deeper > 0.0:
            # Something stands behind (or a descent there was blocked): from inside the rim.
            start = obj - (radius - PUSH_INSET - self._deeper) * self._direction
            start[2] = lo[2] + PUSH_HEIGHT
        elif behind > lo[2] + 0.005:  # something low (a plate's rim): push over it, below the object's top
            start[2] = min(behind + PUSH_OVER, hi[2] - 0.01)
        self._finger_axis = np.array([-self._direction[1], self._direction[0], 0.0])
        return start

    def _retreat_point(self, pos: np.ndarray) -> np.ndarray:
        """Where the hand goes once the object is there: ``RETREAT_HEIGHT`` up."""
        return pos + np.array([0.0, 0.0, RETREAT_HEIGHT])

    def _plan(self, state: WorldState, pos: np.ndarray) -> None:
        """The start of a push from where the object now is, and the height to travel there at."""
        self._anchor = self._start(state)
        self._travel = self._corridor_top(pos, self._anchor, 0.06) + CLEAR_MARGIN + 0.03

    def _decide(self, state: WorldState) -> np.ndarray:
        pos, _ = self._eef()
        if self.phase != "retreat" and self.phase != "done" and self._inside(state):
            self._anchor = self._retreat_point(pos)
            self._enter("retreat")
        if self.phase == "approach":
            if self._phase_steps == 0:
                self._plan(state, pos)
            above = self._anchor.copy()
            above[2] = self._travel
            if pos[2] < self._travel - 0.02 and np.linalg.norm(above[:2] - pos[:2]) > 0.03:
                above[:2] = pos[:2]  # rise before moving sideways
            if np.linalg.norm(above - pos) < POS_TOL or self._phase_steps > PHASE_STEPS:
                self._enter("descend")
            else:
                return self._action(above, CLOSE)
        if self.phase == "descend":
            error = float(np.linalg.norm(self._anchor - pos))
            stuck = self._stuck(error)
            if stuck and pos[2] > self._anchor[2] + PUSH_BLOCKED:  # the hand sits on something: start deeper
                self._deeper = min(self._deeper + PUSH_DEEPER, 2 * PUSH_DEEPER)
                self._enter("approach")
                self._plan(state, pos)
                return self._action(np.append(pos[:2], self._travel), CLOSE)
            if error < POS_TOL or stuck or self._phase_steps > PHASE_STEPS:
                self._enter("push")
            else:
                return self._action(self._anchor, CLOSE, speed=1.0 if error > 0.03 else 0.5)
        if self.phase == "push":
            obj = state.pos[self._subject]
            goal = self._target.point(state, self._data)
            line = obj[:2] - self._anchor[:2]
            drift = abs(float(line @ np.array([-self._direction[1], self._direction[0]])))
            # The fingers start behind the object: it does not move before they reach it.
            stalled = (
                self._stuck(float(np.linalg.norm(goal[:2] - obj[:2]))) and self._phase_steps > 2 * STALL_STEPS
            )
            if drift > PUSH_DRIFT or stalled or self._phase_steps > 4 * PHASE_STEPS:
                self._enter("approach")
                self._plan(state, pos)
                return self._action(np.append(pos[:2], self._travel), CLOSE)
            if self._phase_steps == 0:
                self._integral[:] = 0.0  # the steady offset of the travel is no help against the object
            way = goal[:2] - obj[:2]
            way /= max(float(np.linalg.norm(way)), 1e-9)
            aim = pos.copy()
            # Ahead along the way, and back onto the line through the object's origin (pushing off-centre
            # turns the object aside).
            off_line = (pos[:2] - obj[:2]) - float((pos[:2] - obj[:2]) @ way) * way
            aim[:2] += PUSH_STEP * way - np.clip(off_line, -PUSH_STEP, PUSH_STEP)
            aim[2] = self._anchor[2]
            return self._action(aim, CLOSE, speed=0.5)
        if self.phase == "retreat" and (action := self._retreat(pos, CLOSE)) is not None:
            return action
        return self._hold(CLOSE)
