"""Takeovers (``--takeover alarm|random``): the scripted expert acts for a while in place of the policy.

A caller of the step loop that watches the episode (the cognition's alarm in ``vlaprobe.cognition.alarm``,
or :class:`RandomTakeovers`, the control) asks for a takeover through the episode's
:class:`~vlaprobe.rollout.EpisodeControl` (:meth:`~vlaprobe.rollout.EpisodeControl.take_over`), as it asks for a
drop. :class:`TakeoverDriver` wraps the episode's driver: from the next action on, the scripted expert's action
is executed until the takeover ends, then the policy acts again. ``--takeover-until steps``: it ends after
``steps`` actions; ``subgoal``: when the watcher hands back (:meth:`~vlaprobe.rollout.EpisodeControl.hand_back`,
the cognition once the subgoal current at the takeover's start is done), or after ``steps`` actions (the cap).
The episode may end first. The expert is asked every step whoever acts (as under DAgger), so that its phase
machine follows the episode and it re-plans from wherever the policy left the arm. :class:`Takeovers` is what
the store keeps per episode (one writer, one reader, versioned).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from vlaprobe.envs.base import Observation
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import Json, JsonObject
from vlaprobe.policies.base import PolicyStep

if TYPE_CHECKING:
    from vlaprobe.rollout.loop import StepRecord

FORMAT_VERSION = 2
"""Version of the ``takeovers`` attribute of a stored episode (:meth:`Takeovers.to_json`): 2 added ``until``
and each takeover's ``ended``; version 1 (fixed-length takeovers) still reads."""
CAP, STEPS = "cap", "steps"
"""A takeover's ``ended`` when its actions ran out: the cap under ``until="subgoal"``, the fixed length under
``until="steps"``."""


class TakeoverRequests(Protocol):
    """The side of an episode's control the driver reads (``vlaprobe.rollout.EpisodeControl``)."""

    def take_takeover(self) -> str | None:
        """The reason of a pending takeover request, if any (consumes it)."""
        ...

    def take_hand_back(self) -> str | None:
        """The reason of a pending hand-back request, if any (consumes it)."""
        ...


class ActingDriver(Protocol):
    """What the takeover wraps: a :class:`~vlaprobe.rollout.Driver`."""

    def reset(self) -> None: ...

    def act(self, obs: Observation, prediction: PolicyStep) -> np.ndarray: ...

    def expert_label(self) -> np.ndarray | None: ...


@dataclass
class Takeover:
    """One handover to the expert."""

    row: int
    """The row whose action the expert executed first."""
    reason: str
    """Why: the alarm's reason, or "random"."""
    steps: int = 0
    """Actions the expert executed in this takeover."""
    ended: str = ""
    """Why the expert handed back: the watcher's reason (``"subgoal: NAME"``, ``"goal"``), ``"cap"`` or
    ``"steps"`` (its actions ran out); "" while it acts, or when the episode ended first."""


@dataclass
class Takeovers:
    """An episode's takeovers as the store keeps them (the ``takeovers`` attribute)."""

    mode: str
    """"alarm" or "random"."""
    items: list[Takeover] = field(default_factory=list)
    until: str = "steps"
    """When a takeover hands back: "subgoal" (the watcher, capped) or "steps" (a fixed length; version 1)."""

    @property
    def expert_steps(self) -> int:
        """Actions executed by the expert over the episode."""
        return sum(t.steps for t in self.items)

    def to_json(self) -> JsonObject:
        return {
            "version": FORMAT_VERSION,
            "mode": self.mode,
            "until": self.until,
            "items": [
                {"row": t.row, "reason": t.reason, "steps": t.steps, "ended": t.ended} for t in self.items
            ],
            "expert_steps": self.expert_steps,
        }

    @classmethod
    def from_json(cls, data: Json) -> Takeovers:
        """The stored attribute (versions 1 and 2); a later version than this vlaprobe reads is one error line."""
        version = data.get("version") if isinstance(data, dict) else None
        if version not in (1, FORMAT_VERSION) or not isinstance(data, dict):
            raise VlaprobeError(
                f"an episode's takeovers have version {version!r}, this vlaprobe reads 1 to {FORMAT_VERSION}; "
                "update vlaprobe to read this store"
            )
        items = [
            Takeover(int(i["row"]), str(i["reason"]), int(i["steps"]), str(i.get("ended", "")))
            for i in data["items"]
        ]
        return cls(str(data["mode"]), items, str(data.get("until", "steps")))


class TakeoverDriver:
    """The episode's driver, with the scripted expert acting on each requested takeover until it ends."""

    def __init__(
        self,
        driver: ActingDriver,
        expert: ActingDriver | None,
        control: TakeoverRequests,
        steps: int,
        mode: str,
        until: str = "steps",
    ) -> None:
        """``expert``: the expert driver of the episode; None: the driver's own expert label is the expert's
        action (the dagger driver). ``until``: "steps" (each takeover lasts ``steps`` actions) or "subgoal"
        (until a hand-back request, at most ``steps`` actions)."""
        if steps < 1:
            raise VlaprobeError(f"--takeover-steps must be at least 1, got {steps}")
        if until not in ("subgoal", STEPS):
            raise VlaprobeError(f"--takeover-until must be subgoal or steps, got {until!r}")
        self.driver, self.expert, self.control, self.steps = driver, expert, control, steps
        self.until = until
        self.log = Takeovers(mode, until=until)
        self.acting: Takeover | None = None
        """The takeover whose expert executed the latest action; None when the driver acted."""
        self._row, self._left = 0, 0

    def reset(self) -> None:
        self.driver.reset()
        if self.expert is not None:
            self.expert.reset()
        self.log = Takeovers(self.log.mode, until=self.until)
        self.acting, self._row, self._left = None, 0, 0

    def act(self, obs: Observation, prediction: PolicyStep) -> np.ndarray:
        action = np.asarray(self.driver.act(obs, prediction), dtype=np.float64)
        expert = self.expert.act(obs, prediction) if self.expert is not None else self.driver.expert_label()
        back = self.control.take_hand_back()
        if back is not None and self._left > 0 and self.until != STEPS:
            self.log.items[-1].ended, self._left = back, 0
        reason = self.control.take_takeover()
        if reason is not None and self._left == 0:
            self.log.items.append(Takeover(self._row, reason))
            self._left = self.steps
        self._row += 1
        if self._left == 0 or expert is None:
            self.acting = None
            return action
        self._left -= 1
        self.acting = self.log.items[-1]
        self.acting.steps += 1
        if self._left == 0:
            self.acting.ended = STEPS if self.until == STEPS else CAP
        return np.asarray(expert, dtype=np.float64)

    def expert_label(self) -> np.ndarray | None:
        return self.driver.expert_label()


class Supervisor(Protocol):
    """Watches an episode's records as they come and asks for takeovers (the alarm, or the random control)."""

    def observe(self, record: StepRecord) -> str | None:
        """The reason to hand the next actions to the expert after ``record``, or None."""
        ...

    def hand_back(self) -> str | None:
        """After :meth:`observe`: the reason to hand the next action back to the policy, or None."""
        ...


class RandomTakeovers:
    """The control: ``count`` takeovers asked after rows drawn from ``seed`` (:func:`random_rows`).

    A row that comes while the expert acts (a takeover of variable length may cover it) is put off to the first
    row after the hand-back, so that every drawn row asks once, as the alarm (silent while the expert acts)
    does; the episode may end first."""

    def __init__(self, count: int, seed: int, horizon: int, steps: int) -> None:
        self.rows = random_rows(count, seed, horizon, steps)
        self._asked = 0

    def observe(self, record: StepRecord) -> str | None:
        due = self._asked < len(self.rows) and record.t >= self.rows[self._asked]
        if not due or record.takeover is not None or record.terminal:
            return None
        self._asked += 1
        return "random"

    def hand_back(self) -> str | None:
        """The control hands nothing back itself (under ``--takeover-until subgoal`` the cognition does)."""
        return None


def random_rows(count: int, seed: int, horizon: int, steps: int) -> tuple[int, ...]:
    """``count`` distinct rows in [0, horizon - 1) drawn from ``seed``: at least ``steps`` apart where the
    horizon allows (every takeover then gets its full length), else any distinct rows."""
    span = max(horizon - 1, 1)
    count = min(count, span)
    if count <= 0:
        return ()
    rng = np.random.default_rng([seed, 6151])
    gap = steps - 1 if (count - 1) * (steps - 1) < span - count + 1 else 0
    picks = np.sort(rng.choice(span - (count - 1) * gap, size=count, replace=False))
    return tuple(int(r) for r in picks + np.arange(count) * gap)
