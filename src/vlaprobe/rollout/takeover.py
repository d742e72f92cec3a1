"""Takeovers (``--takeover alarm|random``): the scripted expert acts for a while in place of the policy.

A caller of the step loop that watches the episode (the cognition's alarm in ``vlaprobe.cognition.takeover``,
or :class:`RandomTakeovers`, the control) asks for a takeover through the episode's
:class:`~vlaprobe.rollout.EpisodeControl` (:meth:`~vlaprobe.rollout.EpisodeControl.take_over`), as it asks for a
drop. :class:`TakeoverDriver` wraps the episode's driver: from the next action on, the scripted expert's action
is executed for ``steps`` actions (or until the episode ends), then the policy acts again. The expert is asked
every step whoever acts (as under DAgger), so that its phase machine follows the episode and it re-plans from
wherever the policy left the arm. :class:`Takeovers` is what the store keeps per episode (one writer, one
reader, versioned).
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

FORMAT_VERSION = 1
"""Version of the ``takeovers`` attribute of a stored episode (:meth:`Takeovers.to_json`)."""


class TakeoverRequests(Protocol):
    """The side of an episode's control the driver reads (``vlaprobe.rollout.EpisodeControl``)."""

    def take_takeover(self) -> str | None:
        """The reason of a pending takeover request, if any (consumes it)."""
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


@dataclass
class Takeovers:
    """An episode's takeovers as the store keeps them (the ``takeovers`` attribute)."""

    mode: str
    """"alarm" or "random"."""
    items: list[Takeover] = field(default_factory=list)

    @property
    def expert_steps(self) -> int:
        """Actions executed by the expert over the episode."""
        return sum(t.steps for t in self.items)

    def to_json(self) -> JsonObject:
        return {
            "version": FORMAT_VERSION,
            "mode": self.mode,
            "items": [{"row": t.row, "reason": t.reason, "steps": t.steps} for t in self.items],
            "expert_steps": self.expert_steps,
        }

    @classmethod
    def from_json(cls, data: Json) -> Takeovers:
        """The stored attribute; a later version than this vlaprobe reads is one error line."""
        version = data.get("version") if isinstance(data, dict) else None
        if version != FORMAT_VERSION:
            raise VlaprobeError(
                f"an episode's takeovers have version {version!r}, this vlaprobe reads {FORMAT_VERSION}; "
                "update vlaprobe to read this store"
            )
        items = [Takeover(int(i["row"]), str(i["reason"]), int(i["steps"])) for i in data["items"]]
        return cls(str(data["mode"]), items)


class TakeoverDriver:
    """The episode's driver, with the scripted expert acting ``steps`` actions per requested takeover."""

    def __init__(
        self,
        driver: ActingDriver,
        expert: ActingDriver | None,
        control: TakeoverRequests,
        steps: int,
        mode: str,
    ) -> None:
        """``expert``: the expert driver of the episode; None: the driver's own expert label is the expert's
        action (the dagger driver)."""
        if steps < 1:
            raise VlaprobeError(f"--takeover-steps must be at least 1, got {steps}")
        self.driver, self.expert, self.control, self.steps = driver, expert, control, steps
        self.log = Takeovers(mode)
        self.acting: Takeover | None = None
        """The takeover whose expert executed the latest action; None when the driver acted."""
        self._row, self._left = 0, 0

    def reset(self) -> None:
        self.driver.reset()
        if self.expert is not None:
            self.expert.reset()
        self.log = Takeovers(self.log.mode)
        self.acting, self._row, self._left = None, 0, 0

    def act(self, obs: Observation, prediction: PolicyStep) -> np.ndarray:
        action = np.asarray(self.driver.act(obs, prediction), dtype=np.float64)
        expert = self.expert.act(obs, prediction) if self.expert is not None else self.driver.expert_label()
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
        return np.asarray(expert, dtype=np.float64)

    def expert_label(self) -> np.ndarray | None:
        return self.driver.expert_label()


class Supervisor(Protocol):
    """Watches an episode's records as they come and asks for takeovers (the alarm, or the random control)."""

    def observe(self, record: StepRecord) -> str | None:
        """The reason to hand the next actions to the expert after ``record``, or None."""
        ...


class RandomTakeovers:
    """The control: ``count`` takeovers asked after rows drawn from ``seed`` (:func:`random_rows`)."""

    def __init__(self, count: int, seed: int, horizon: int, steps: int) -> None:
        self.rows = random_rows(count, seed, horizon, steps)

    def observe(self, record: StepRecord) -> str | None:
        return "random" if record.t in self.rows else None


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
