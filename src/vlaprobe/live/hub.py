"""Fan-out of the running episode to every connected client, without letting one slow client hold up others.

The episode is kept once, as a log shared by all clients: the ``episode_start`` text, every step's state
(JSON without the image), the ``episode_end`` text, and only the newest frame. Each client has a cursor into
the log and its own sender task, so a client that reads slowly only falls behind: it still gets every step
state in order (never lost, never copied per client), and each time it catches up it gets the newest image
(intermediate images are dropped, at most ``image_hz`` per second). Memory is one episode's states plus a
few small control messages per client, however many clients and however slow.

Everything here runs on the event loop's thread; the episode thread calls in through
:meth:`Hub.threadsafe`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from typing_extensions import TypeVarTuple, Unpack

Ts = TypeVarTuple("Ts")

PRIVATE_LIMIT = 64
"""Control messages (errors, hello) kept per client; the oldest are dropped beyond this."""
ERROR_BACKLOG = 32
"""Unsent error replies kept per client: a client that sends bad frames faster than it reads the replies gets
the first 32, then one error saying how many more were suppressed (docs/live.md)."""
ERROR_PREFIX = '{"type":"error"'
"""How an error reply's JSON text begins (pydantic's compact dump of ``ErrorMessage``)."""
SEND_TIMEOUT = 60.0
"""Seconds one send may wait on a client that reads nothing before that client is closed (1008): it would
otherwise keep an old episode's log alive for as long as its connection stays open."""


class Sink(Protocol):
    """The client's connection as the hub sees it."""

    async def send_text(self, data: str) -> None: ...

    async def close(self, code: int = 1000, reason: str | None = None) -> None: ...


@dataclass
class EpisodeLog:
    """One episode as sent to clients."""

    episode_id: str
    start: str
    states: list[str] = field(default_factory=list)
    """Each step's message without its image (JSON text of an object)."""
    image: str | None = None
    """Base64 JPEG of the newest step."""
    image_index: int = -1
    end: str | None = None


def with_image(state: str, image: str | None) -> str:
    """A step's JSON text with its ``image`` field added (states are stored without it)."""
    return state[:-1] + (',"image":null}' if image is None else ',"image":"' + image + '"}')


def history_text(log: EpisodeLog, n: int) -> str:
    steps = ",".join(with_image(s, None) for s in log.states[:n])
    return f'{{"type":"history","episode_id":"{log.episode_id}","start":{log.start},"steps":[{steps}]}}'


@dataclass(eq=False)
class Client:
    sink: Sink
    image_hz: float
    paper: bool = False
    """Sent a bare instruction (the paper's client): every step it gets carries an image, the newest frame (the
    paper's UI shows ``image`` of every message; a lagging client sees the newest frame, not a stale one)."""
    log: EpisodeLog | None = None
    pos: int = -1
    """Next step index to send from ``log``; -1: its start is not sent yet."""
    end_sent: bool = False
    history: bool = False
    """Joined mid-episode: the first message of ``log`` is a ``history``."""
    last_image: float = 0.0
    private: deque[str] = field(default_factory=lambda: deque(maxlen=PRIVATE_LIMIT))
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    closed: bool = False
    suppressed: int = 0
    """Error replies not queued since the backlog was full (announced once it drains)."""


def _errors_in(c: Client) -> int:
    return sum(text.startswith(ERROR_PREFIX) for text in c.private)


class Hub:
    """The current episode and the connected clients."""

    def __init__(
        self, loop: asyncio.AbstractEventLoop | None = None, send_timeout: float = SEND_TIMEOUT
    ) -> None:
        self.loop, self.send_timeout = loop, send_timeout
        self.clients: set[Client] = set()
        self.current: EpisodeLog | None = None

    def threadsafe(self, fn: Callable[[Unpack[Ts]], object], *args: Unpack[Ts]) -> None:
        """Run ``fn(*args)`` on the event loop's thread (from the episode thread)."""
        if self.loop is None or self.loop.is_closed():
            return  # the server has shut down; nobody is left to tell
        with contextlib.suppress(RuntimeError):  # closed between the check and the call
            self.loop.call_soon_threadsafe(fn, *args)

    def _notify(self) -> None:
        for c in self.clients:
            c.wake.set()

    # -- episode side -----------------------------------------------------------------------------
    def begin(self, episode_id: str, start: str) -> None:
        self.current = EpisodeLog(episode_id, start)
        self._notify()

    def step(self, state: str, image: str | None) -> None:
        log = self.current
        if log is None:
            return
        log.states.append(state)
        if image is not None:
            log.image, log.image_index = image, len(log.states) - 1
        self._notify()

    def end(self, end: str) -> None:
        if self.current is not None:
            self.current.end = end
        self._notify()

    def broadcast(self, text: str) -> None:
        for c in self.clients:
            c.private.append(text)
        self._notify()

    # -- client side ------------------------------------------------------------------------------
    def add(self, sink: Sink, image_hz: float) -> Client:
        c = Client(sink, image_hz)
        cur = self.current
        if cur is not None and cur.end is None:
            c.log, c.history = cur, bool(cur.states)
        elif cur is not None:
            c.log, c.pos, c.end_sent = cur, len(cur.states), True  # already over: wait for the next one
        self.clients.add(c)
        return c

    def remove(self, c: Client) -> None:
        c.closed = True
        c.wake.set()
        self.clients.discard(c)

    def tell(self, c: Client, text: str) -> None:
        c.private.append(text)
        c.wake.set()

    def tell_error(self, c: Client, text: str) -> None:
        """Queue an error reply for ``c`` alone, or count it as suppressed when ``ERROR_BACKLOG`` wait unsent."""
        if _errors_in(c) >= ERROR_BACKLOG:
            c.suppressed += 1
            return
        self.tell(c, text)

    def _suppressed_notice(self, c: Client) -> str | None:
        if not c.suppressed or _errors_in(c):
            return None
        n, c.suppressed = c.suppressed, 0
        return json.dumps(
            {
                "type": "error",
                "message": f"{n} more errors suppressed (bad frames sent faster than their replies were read)",
            }
        )

    async def _send(self, c: Client, text: str) -> None:
        try:
            await asyncio.wait_for(c.sink.send_text(text), self.send_timeout)
        except asyncio.TimeoutError:
            self.remove(c)
            c.log = None
            c.private.clear()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(c.sink.close(1008, "client reads nothing"), 1.0)
            raise

    async def run_sender(self, c: Client) -> None:
        """Send the client everything due, in order, until it is removed (or reads nothing for send_timeout)."""
        with contextlib.suppress(asyncio.TimeoutError):
            await self._run_sender(c)

    async def _run_sender(self, c: Client) -> None:
        while not c.closed:
            c.wake.clear()
            sent = False
            while c.private:
                await self._send(c, c.private.popleft())
                sent = True
            notice = self._suppressed_notice(c)
            if notice is not None:
                await self._send(c, notice)
                sent = True
            cur = self.current
            if (c.log is None or c.end_sent) and cur is not None and cur is not c.log:
                c.log, c.pos, c.end_sent, c.history = cur, -1, False, False
            log = c.log
            if log is not None and not c.end_sent:
                sent |= await self._send_log(c, log)
            if not sent:
                await c.wake.wait()

    async def _send_log(self, c: Client, log: EpisodeLog) -> bool:
        sent = False
        if c.pos == -1:
            n = len(log.states)
            if c.history and n:
                await self._send(c, history_text(log, n))
                c.pos = n
            else:
                await self._send(c, log.start)
                c.pos = 0
            sent = True
        while c.pos < len(log.states) and not c.closed:
            i = c.pos
            image = None
            if c.paper:
                image = log.image
            elif i == log.image_index == len(log.states) - 1:
                now = time.monotonic()
                if now - c.last_image >= 1.0 / c.image_hz:
                    image, c.last_image = log.image, now
            await self._send(c, with_image(log.states[i], image))
            c.pos += 1
            sent = True
        if log.end is not None and c.pos >= len(log.states) and not c.end_sent:
            await self._send(c, log.end)
            c.end_sent = True
            sent = True
        return sent
