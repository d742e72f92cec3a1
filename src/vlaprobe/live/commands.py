"""What a client frame does: parsed into a protocol command (or matched against the task instructions, for
the paper's client), checked, then acted on. Anything wrong raises :class:`VlaprobeError` with the one line the
sender gets back; a start that fails in the episode thread before its first step is told to the sender only.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import TYPE_CHECKING

from pydantic import ValidationError

from vlaprobe.errors import VlaprobeError
from vlaprobe.live import protocol as P
from vlaprobe.live.hub import Client, Hub
from vlaprobe.live.session import Session, public_message
from vlaprobe.rollout import EpisodeControl

if TYPE_CHECKING:
    from vlaprobe.live.app import Engine, Limits


def error_text(message: str) -> str:
    """An ``error`` message's JSON: one line, no server paths."""
    return P.ErrorMessage(message=public_message(message)).model_dump_json()


def one_line(exc: ValidationError) -> str:
    err = exc.errors()[0]
    where = ".".join(str(x) for x in err.get("loc", ())) or "message"
    return f"invalid message ({where}: {err['msg']}); see the protocol in docs/live.md"


class Commands:
    """Acts on client frames for one server (any client may control the running episode)."""

    def __init__(self, engine: Engine, limits: Limits, session: Session, hub: Hub) -> None:
        self.engine, self.limits, self.session, self.hub = engine, limits, session, hub
        self.rng = random.Random(limits.seed)

    def handle(self, client: Client, text: str) -> None:
        """Act on one frame of ``client``; raises VlaprobeError with the message for the client."""
        stripped = text.strip()
        if not stripped.startswith("{"):
            if not stripped:
                raise VlaprobeError("empty message; send a JSON command or a task instruction")
            task = self.engine.simulator.resolve_task(stripped)
            client.paper = True
            self.start(client, P.StartCommand(task=task, driver=self.limits.default_driver))  # type: ignore[arg-type]
            return
        try:
            cmd = P.CLIENT.validate_json(text)
        except ValidationError as exc:
            raise VlaprobeError(one_line(exc)) from None
        if isinstance(cmd, P.StartCommand):
            self.start(client, cmd)
        elif isinstance(cmd, P.ReplayCommand):
            self.replay(client, cmd)
        else:
            self.control(cmd)

    def _tell(self, client: Client) -> Callable[[str], None]:
        return lambda message: self.hub.tell_error(client, error_text(message))

    def start(self, client: Client, cmd: P.StartCommand) -> None:
        sim = self.engine.simulator
        task = sim.resolve_task(cmd.task)
        sim.check_start(task, cmd.init, cmd.max_steps, cmd.driver)
        seed = self.rng.randrange(2**31)
        self.session.start(
            task,
            "live",
            lambda: sim.source(task, cmd.init, cmd.driver, cmd.max_steps, seed),
            EpisodeControl(),
            True,
            on_error=self._tell(client),
        )

    def replay(self, client: Client, cmd: P.ReplayCommand) -> None:
        replays = self.engine.replays
        if replays is None:
            raise VlaprobeError("no store to replay from; start the server with --store DIR")
        info = replays.episodes.infos.get(cmd.episode_id)
        if info is None:
            raise VlaprobeError(f"no stored episode {cmd.episode_id[:80]!r}; GET /api/episodes lists them")
        hz = cmd.hz or self.limits.replay_hz
        self.session.start(  # the episode is read (and its chunks checked) in the episode thread
            info.task,
            "replay",
            lambda: replays.source(cmd.episode_id, hz),
            EpisodeControl(),
            False,
            on_error=self._tell(client),
        )

    def control(self, cmd: P.StopCommand | P.PauseCommand | P.ResumeCommand | P.DropCommand) -> None:
        """stop, pause, resume or drop: act on the running episode."""
        run = self.session.running
        if run is None:
            raise VlaprobeError(f"no episode is running; {cmd.type} needs one (send start first)")
        if isinstance(cmd, P.StopCommand):
            run.control.stop()  # a paused episode wakes up to end
        elif isinstance(cmd, P.PauseCommand | P.ResumeCommand):
            if isinstance(cmd, P.PauseCommand):
                run.control.pause()
            else:
                run.control.resume()
            status = P.Status(episode_id=run.episode_id, paused=bool(run.control.paused))
            self.hub.broadcast(status.model_dump_json())
        elif isinstance(cmd, P.DropCommand):
            if run.source != "live":
                raise VlaprobeError("drop perturbs the simulator; it works in live episodes only")
            run.control.drop(cmd.steps or 8)
