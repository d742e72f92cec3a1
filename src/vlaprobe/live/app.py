"""The FastAPI app: the WebSocket endpoint ``/ws``, the REST API of recorded episodes, the web UI at ``/``.

Client input never reaches the episode unchecked (:mod:`vlaprobe.live.commands`): anything wrong gets a
one-line ``error`` message to its sender and the connection stays usable. Frames over the size limit close
that connection (1009); a foreign Host header is refused before any route (421, or 403 for a WebSocket
handshake: :mod:`vlaprobe.live.guard`), a bad token or a foreign browser Origin before the WebSocket is
accepted (1008). Reads of episodes run in a paced worker (:mod:`vlaprobe.live.rest`).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path

from fastapi import FastAPI, HTTPException, Request, WebSocket
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from starlette.websockets import WebSocketDisconnect

from vlaprobe import __version__
from vlaprobe.cognition.budget import interrupt_solves
from vlaprobe.errors import VlaprobeError
from vlaprobe.live import protocol as P
from vlaprobe.live.commands import Commands, error_text
from vlaprobe.live.guard import HostGuard, Hosts, origin_ok, token_ok
from vlaprobe.live.hub import Hub
from vlaprobe.live.pipeline import EpisodeSpec, StepBuilder
from vlaprobe.live.recorder import Recordings
from vlaprobe.live.replay import StoreReplays
from vlaprobe.live.rest import Reader, add_rest
from vlaprobe.live.session import Session
from vlaprobe.live.sources import Simulator

UI_FOLDER = Path(__file__).with_name("ui")
NO_UI_PAGE = (
    "<!doctype html><title>vlaprobe live</title><p>The web UI is not built: run <code>make ui</code> "
    "(npm ci &amp;&amp; npm run build in web/). The WebSocket is at <code>/ws</code>, episodes at "
    "<code>/api/episodes</code>.</p>"
)


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
    host: str = "127.0.0.1"
    """The bound address: with loopback names and the hosts of ``origins``, the Host headers answered."""
    max_message_bytes: int = 65536
    image_hz: float = 10.0
    replay_hz: float = 10.0
    default_driver: str = "expert"
    seed: int = 0
    read_duty: float = 0.25
    """Most of the time episode reads may take while an episode runs (:class:`vlaprobe.live.rest.Reader`)."""
    ui: Path = field(default_factory=lambda: UI_FOLDER)


def create_app(engine: Engine, limits: Limits) -> FastAPI:
    """The app: ``/ws``, ``/api/episodes...`` and the UI, behind the Host check."""
    hub = Hub()
    session = Session(hub, engine.make_builder, engine.recordings, on_exit=engine.simulator.close)
    recordings = Recordings(engine.recordings) if engine.recordings is not None else None
    reader = Reader(recordings, engine.replays, lambda: session.running is not None, duty=limits.read_duty)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        hub.loop = asyncio.get_running_loop()
        yield
        reader.close()
        interrupt_solves()  # a step solving users' rules ends now, not at its budget
        await asyncio.to_thread(session.close)

    app = FastAPI(
        title="vlaprobe live", version=__version__, lifespan=lifespan, docs_url=None, redoc_url=None
    )
    app.state.hub, app.state.session = hub, session
    app.add_middleware(HostGuard, hosts=Hosts(limits.host, limits.origins))
    add_websocket(app, engine, limits, Commands(engine, limits, session, hub))

    def check_rest(request: Request) -> None:
        auth = request.headers.get("authorization", "")
        presented = auth[7:] if auth.lower().startswith("bearer ") else request.query_params.get("token")
        if not token_ok(limits.token, presented):
            raise HTTPException(401, "token required: Authorization: Bearer <token> or ?token=")

    add_rest(app, reader, check_rest)
    add_ui(app, limits.ui)
    return app


def hello_text(engine: Engine, session: Session) -> str:
    run = session.running
    running = None if run is None else P.Running(episode_id=run.episode_id, paused=bool(run.control.paused))
    return engine.hello.model_copy(update={"running": running}).model_dump_json()


def add_websocket(app: FastAPI, engine: Engine, limits: Limits, commands: Commands) -> None:
    """``/ws``: checks before accepting, then a receive loop feeding :class:`Commands` and one sender task."""
    hub, session = commands.hub, commands.session

    @app.websocket("/ws")
    async def ws_endpoint(ws: WebSocket) -> None:
        if not token_ok(limits.token, ws.query_params.get("token")):
            await ws.close(code=1008, reason="token required: connect to /ws?token=...")
            return
        if not origin_ok(limits.origins, ws.headers.get("origin"), ws.headers.get("host")):
            await ws.close(code=1008, reason="origin not allowed (ServeConfig.origins)")
            return
        await ws.accept()
        client = hub.add(ws, limits.image_hz)
        hub.tell(client, hello_text(engine, session))
        sender = asyncio.create_task(hub.run_sender(client))
        try:
            while True:
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    break
                text = msg.get("text")
                if text is None:
                    hub.tell_error(client, error_text("binary frames are not accepted; send JSON text"))
                    continue
                if len(text) > limits.max_message_bytes:
                    await ws.close(code=1009, reason="message too big")
                    break
                try:
                    commands.handle(client, text)
                except VlaprobeError as exc:
                    hub.tell_error(client, error_text(str(exc)))
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            hub.remove(client)
            sender.cancel()
            with contextlib.suppress(BaseException):
                await sender


def add_ui(app: FastAPI, ui: Path) -> None:
    """The built web UI at ``/``, or a one-line page saying how to build it."""
    if (ui / "index.html").is_file():
        app.mount("/", StaticFiles(directory=ui, html=True), name="ui")
        return

    @app.get("/", response_class=HTMLResponse)
    def no_ui() -> str:
        return NO_UI_PAGE
