"""The FastAPI app: the WebSocket endpoint ``/ws``, the REST API of recorded episodes, the web UI at ``/``.

Client input never reaches the episode unchecked: every frame is parsed into a protocol model (or matched
against the task instructions, for the paper's client); anything else gets a one-line ``error`` message and
the connection stays usable. Frames over the size limit close that connection (1009); a bad token or a
foreign browser Origin is refused before the WebSocket is accepted (1008).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import random
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from fastapi import FastAPI, HTTPException, Request, WebSocket
from fastapi.responses import HTMLResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import ValidationError
from starlette.websockets import WebSocketDisconnect

from vlaprobe import __version__
from vlaprobe.errors import VlaprobeError
from vlaprobe.live import protocol as P
from vlaprobe.live.hub import Hub
from vlaprobe.live.pipeline import EpisodeSpec, StepBuilder
from vlaprobe.live.recorder import Recordings
from vlaprobe.live.replay import StoreReplays
from vlaprobe.live.session import Session, encode_jpeg
from vlaprobe.live.sources import Simulator
from vlaprobe.rollout import EpisodeControl

UI_FOLDER = Path(__file__).with_name("ui")
NO_UI_PAGE = (
    "<!doctype html><title>vlaprobe live</title><p>The web UI is not built: run <code>make ui</code> "
    "(npm ci &amp;&amp; npm run build in web/). The WebSocket is at <code>/ws</code>, episodes at "
    "<code>/api/episodes</code>.</p>"
)
LOOPBACK = {"localhost", "127.0.0.1", "::1"}


@dataclass
class Engine:
    """Everything the app serves, built by :func:`vlaprobe.live.serve.build_engine` (or by tests with fakes)."""

    hello: P.Hello
    """The greeting (``running`` is filled per connection)."""
    simulator: Simulator
    make_builder: Callable[[EpisodeSpec, str], StepBuilder]
    recordings: Path | None
    replays: StoreReplays | None = None


@dataclass
class Limits:
    """The server's security and pacing settings (from ServeConfig)."""

    token: str | None = None
    origins: tuple[str, ...] = ()
    max_message_bytes: int = 65536
    image_hz: float = 10.0
    replay_hz: float = 10.0
    default_driver: str = "expert"
    seed: int = 0
    ui: Path = field(default_factory=lambda: UI_FOLDER)


def _token_ok(limits: Limits, presented: str | None) -> bool:
    if limits.token is None:
        return True
    return presented is not None and hmac.compare_digest(presented.encode(), limits.token.encode())


def _origin_ok(limits: Limits, origin: str | None, host: str | None) -> bool:
    """Browsers send Origin: allow the server's own address, loopback pages and configured origins."""
    if origin is None:
        return True  # not a browser (the Java client, websockets); the token guards those
    if origin in limits.origins:
        return True
    parts = urlsplit(origin)
    return parts.hostname in LOOPBACK or (host is not None and parts.netloc == host)


def _one_line(exc: ValidationError) -> str:
    err = exc.errors()[0]
    where = ".".join(str(x) for x in err.get("loc", ())) or "message"
    return f"invalid message ({where}: {err['msg']}); see the protocol in docs/live.md"


def create_app(engine: Engine, limits: Limits) -> FastAPI:
    hub = Hub()
    session = Session(hub, engine.make_builder, engine.recordings, on_exit=engine.simulator.close)
    recordings = Recordings(engine.recordings) if engine.recordings is not None else None
    rng = random.Random(limits.seed)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> Any:
        hub.loop = asyncio.get_running_loop()
        yield
        await asyncio.to_thread(session.close)

    app = FastAPI(
        title="vlaprobe live", version=__version__, lifespan=lifespan, docs_url=None, redoc_url=None
    )
    app.state.hub, app.state.session = hub, session

    def hello_text() -> str:
        run = session.running
        return engine.hello.model_copy(
            update={
                "running": None
                if run is None
                else P.Running(episode_id=run.episode_id, paused=bool(run.control.paused))
            }
        ).model_dump_json()

    def error(message: str) -> str:
        return P.ErrorMessage(message=message.splitlines()[0][:500]).model_dump_json()

    def start(cmd: P.StartCommand) -> None:
        sim = engine.simulator
        task = sim.resolve_task(cmd.task)
        seed = rng.randrange(2**31)
        session.start(
            task,
            "live",
            lambda: sim.source(task, cmd.init, cmd.driver, cmd.max_steps, seed),
            EpisodeControl(),
            True,
        )

    def replay(cmd: P.ReplayCommand) -> None:
        if engine.replays is None:
            raise VlaprobeError("no store to replay from; start the server with --store DIR")
        spec = engine.replays.episodes.spec(cmd.episode_id)
        hz = cmd.hz or limits.replay_hz
        session.start(
            spec.task, "replay", lambda: engine.replays.source(cmd.episode_id, hz), EpisodeControl(), False
        )

    def command(client: Any, text: str) -> None:
        """Act on one client frame; raises VlaprobeError with the message for the client."""
        stripped = text.strip()
        if not stripped.startswith("{"):
            if not stripped:
                raise VlaprobeError("empty message; send a JSON command or a task instruction")
            task = engine.simulator.resolve_task(stripped)
            client.paper = True
            start(P.StartCommand(task=task, driver=limits.default_driver))
            return
        try:
            cmd = P.CLIENT.validate_json(text)
        except ValidationError as exc:
            raise VlaprobeError(_one_line(exc)) from None
        if isinstance(cmd, P.StartCommand):
            start(cmd)
        elif isinstance(cmd, P.ReplayCommand):
            replay(cmd)
        else:
            run = session.running
            if run is None:
                raise VlaprobeError(f"no episode is running; {cmd.type} needs one (send start first)")
            if isinstance(cmd, P.StopCommand):
                run.control.stop()
            elif isinstance(cmd, P.PauseCommand | P.ResumeCommand):
                if isinstance(cmd, P.PauseCommand):
                    run.control.pause()
                else:
                    run.control.resume()
                status = P.Status(episode_id=run.episode_id, paused=bool(run.control.paused))
                hub.broadcast(status.model_dump_json())
            elif isinstance(cmd, P.DropCommand):
                if run.source != "live":
                    raise VlaprobeError("drop perturbs the simulator; it works in live episodes only")
                run.control.drop(cmd.steps or 8)

    @app.websocket("/ws")
    async def ws_endpoint(ws: WebSocket) -> None:
        if not _token_ok(limits, ws.query_params.get("token")):
            await ws.close(code=1008, reason="token required: connect to /ws?token=...")
            return
        if not _origin_ok(limits, ws.headers.get("origin"), ws.headers.get("host")):
            await ws.close(code=1008, reason="origin not allowed (ServeConfig.origins)")
            return
        await ws.accept()
        client = hub.add(ws, limits.image_hz)
        hub.tell(client, hello_text())
        sender = asyncio.create_task(hub.run_sender(client))
        try:
            while True:
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    break
                text = msg.get("text")
                if text is None:
                    hub.tell(client, error("binary frames are not accepted; send JSON text"))
                    continue
                if len(text) > limits.max_message_bytes:
                    await ws.close(code=1009, reason="message too big")
                    break
                try:
                    command(client, text)
                except VlaprobeError as exc:
                    hub.tell(client, error(str(exc)))
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            hub.remove(client)
            sender.cancel()
            with contextlib.suppress(BaseException):
                await sender

    def check_rest(request: Request) -> None:
        auth = request.headers.get("authorization", "")
        presented = auth[7:] if auth.lower().startswith("bearer ") else request.query_params.get("token")
        if not _token_ok(limits, presented):
            raise HTTPException(401, "token required: Authorization: Bearer <token> or ?token=")

    @app.get("/api/episodes", response_model=list[P.EpisodeListItem])
    def list_episodes(request: Request) -> list[P.EpisodeListItem]:
        check_rest(request)
        items = recordings.list() if recordings is not None else []
        if engine.replays is not None:
            items += engine.replays.episodes.list()
        return items

    @app.get("/api/episodes/{episode_id}", response_model=P.EpisodeRecord)
    def get_episode(episode_id: str, request: Request) -> P.EpisodeRecord:
        check_rest(request)
        record = recordings.get(episode_id) if recordings is not None else None
        if record is None and engine.replays is not None and episode_id in engine.replays.episodes.infos:
            record = engine.replays.record(episode_id)
        if record is None:
            raise HTTPException(404, f"no episode {episode_id!r}; GET /api/episodes lists them")
        return record

    @app.get("/api/episodes/{episode_id}/frames/{t}")
    def get_frame(episode_id: str, t: int, request: Request) -> Response:
        check_rest(request)
        data = recordings.frame(episode_id, t) if recordings is not None else None
        if data is None and engine.replays is not None:
            image = engine.replays.episodes.image(episode_id, t)
            data = None if image is None else encode_jpeg(image)
        if data is None:
            raise HTTPException(404, f"no frame {t} of episode {episode_id!r}")
        return Response(data, media_type="image/jpeg")

    if (limits.ui / "index.html").is_file():
        app.mount("/", StaticFiles(directory=limits.ui, html=True), name="ui")
    else:

        @app.get("/", response_class=HTMLResponse)
        def no_ui() -> str:
            return NO_UI_PAGE

    return app
