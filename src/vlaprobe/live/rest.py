"""The REST API of recorded and stored episodes, read so that readers cannot starve the live episode.

Reading an episode is heavy: a stored one goes through the probes and the cognition step by step, a recorded
one is parsed line by line. :class:`Reader` runs every read in ONE worker thread with a bounded queue (beyond
``limit`` waiting reads: 503 "retry"), paces it to at most ``duty`` of the time while an episode runs, and keeps
the JSON of finished episodes (stored ones, and recordings with their end) in a cache bounded in bytes. With 8
clients fetching store episodes in parallel the live episode keeps >= 80% of its quiet step rate
(``bench/live.py``).
"""

from __future__ import annotations

import asyncio
import json
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from fastapi import FastAPI, HTTPException, Request
from fastapi.responses import Response
from typing_extensions import TypeVarTuple, Unpack

from vlaprobe.errors import VlaprobeError
from vlaprobe.live import protocol as P
from vlaprobe.live.recorder import Recordings
from vlaprobe.live.replay import StoreReplays
from vlaprobe.live.session import encode_jpeg, public_message

T = TypeVar("T")
Ts = TypeVarTuple("Ts")
CACHE_BYTES = 64 << 20
"""JSON of finished episodes kept for repeated reads (a LIBERO episode of the tiny model: ~1 MB)."""


class Busy(Exception):
    """Too many reads are waiting."""


class Reader:
    """Episode reads in one paced worker thread, finished episodes' JSON cached."""

    def __init__(
        self,
        recordings: Recordings | None,
        replays: StoreReplays | None,
        live: Callable[[], bool],
        *,
        duty: float = 0.25,
        limit: int = 32,
        cache_bytes: int = CACHE_BYTES,
    ) -> None:
        """``live``: whether an episode runs now (reads are paced only then)."""
        self.recordings, self.replays, self.live = recordings, replays, live
        self.duty, self.limit, self.cache_bytes = duty, limit, cache_bytes
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="episode-reads")
        self._waiting = 0
        self._free_at = 0.0
        self._cache: OrderedDict[str, bytes] = OrderedDict()
        self._cached = 0
        self._lock = threading.Lock()

    async def run(self, fn: Callable[[Unpack[Ts]], T], *args: Unpack[Ts]) -> T:
        """``fn(*args)`` in the worker; :class:`Busy` when ``limit`` reads already wait."""
        if self._waiting >= self.limit:
            raise Busy
        self._waiting += 1
        try:
            return await asyncio.get_running_loop().run_in_executor(self._pool, self._paced, fn, args)
        finally:
            self._waiting -= 1

    def _paced(self, fn: Callable[[Unpack[Ts]], T], args: tuple[Unpack[Ts]]) -> T:
        wait = self._free_at - time.monotonic()
        if wait > 0 and self.live():
            time.sleep(wait)
        t0 = time.monotonic()
        try:
            return fn(*args)
        finally:
            took = time.monotonic() - t0
            self._free_at = time.monotonic() + took * (1.0 / self.duty - 1.0)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)

    # -- reads (in the worker) --------------------------------------------------------------------
    def listing(self) -> bytes:
        items = self.recordings.list() if self.recordings is not None else []
        if self.replays is not None:
            items += self.replays.episodes.list()
        return json.dumps([i.model_dump(mode="json") for i in items]).encode()

    def episode(self, episode_id: str) -> bytes | None:
        with self._lock:
            if episode_id in self._cache:
                self._cache.move_to_end(episode_id)
                return self._cache[episode_id]
        record = self.recordings.get(episode_id) if self.recordings is not None else None
        if record is None and self.replays is not None and episode_id in self.replays.episodes.infos:
            record = self.replays.record(episode_id)
        if record is None:
            return None
        data = record.model_dump_json().encode()
        if record.end is not None:  # finished: it never changes
            self._keep(episode_id, data)
        return data

    def _keep(self, key: str, data: bytes) -> None:
        with self._lock:
            self._cache[key] = data
            self._cached += len(data)
            while self._cached > self.cache_bytes and len(self._cache) > 1:
                _, old = self._cache.popitem(last=False)
                self._cached -= len(old)

    def frame(self, episode_id: str, t: int) -> bytes | None:
        data = self.recordings.frame(episode_id, t) if self.recordings is not None else None
        if data is None and self.replays is not None and episode_id in self.replays.episodes.infos:
            image = self.replays.episodes.image(episode_id, t)
            data = None if image is None else encode_jpeg(image)
        return data


def _refused(exc: Exception) -> HTTPException:
    if isinstance(exc, Busy):
        return HTTPException(503, "too many episode reads are waiting; retry in a moment")
    print(f"vlaprobe serve: {exc}", file=sys.stderr)  # the operator's log keeps the full message
    return HTTPException(422, public_message(str(exc)))


def add_rest(app: FastAPI, reader: Reader, check: Callable[[Request], None]) -> None:
    """``GET /api/episodes``, ``/api/episodes/{id}``, ``/api/episodes/{id}/frames/{t}`` (docs/live.md)."""

    @app.get("/api/episodes", response_model=list[P.EpisodeListItem])
    async def list_episodes(request: Request) -> Response:
        check(request)
        try:
            data = await reader.run(reader.listing)
        except (Busy, VlaprobeError) as exc:
            raise _refused(exc) from None
        return Response(data, media_type="application/json")

    @app.get("/api/episodes/{episode_id}", response_model=P.EpisodeRecord)
    async def get_episode(episode_id: str, request: Request) -> Response:
        check(request)
        try:
            data = await reader.run(reader.episode, episode_id)
        except (Busy, VlaprobeError) as exc:
            raise _refused(exc) from None
        if data is None:
            raise HTTPException(404, f"no episode {episode_id[:80]!r}; GET /api/episodes lists them")
        return Response(data, media_type="application/json")

    @app.get("/api/episodes/{episode_id}/frames/{t}")
    async def get_frame(episode_id: str, t: int, request: Request) -> Response:
        check(request)
        try:
            data = await reader.run(reader.frame, episode_id, t)
        except (Busy, VlaprobeError) as exc:
            raise _refused(exc) from None
        if data is None:
            raise HTTPException(404, f"no frame {t} of episode {episode_id[:80]!r}")
        return Response(data, media_type="image/jpeg")
