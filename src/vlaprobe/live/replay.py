"""Store episodes through the probes and the cognition, without the simulator: streamed, or whole for REST."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable

from vlaprobe.live import protocol as P
from vlaprobe.live.pipeline import EpisodeSpec, StepBuilder
from vlaprobe.live.sources import StoreEpisodes, StoreSource

CACHE_EPISODES = 8
"""Whole replays kept for repeated REST reads (each is one episode's step states, a few MB at most)."""


class StoreReplays:
    """Replays of one activation store's episodes."""

    def __init__(
        self, episodes: StoreEpisodes, make_builder: Callable[[EpisodeSpec, str], StepBuilder]
    ) -> None:
        self.episodes, self.make_builder = episodes, make_builder
        self._cache: OrderedDict[str, P.EpisodeRecord] = OrderedDict()
        self._lock = threading.Lock()

    def source(self, episode_id: str, hz: float | None) -> StoreSource:
        return self.episodes.source(episode_id, hz)

    def record(self, episode_id: str) -> P.EpisodeRecord:
        """Every step of a stored episode as the live server would have sent it (images at .../frames/{t})."""
        with self._lock:
            if episode_id in self._cache:
                self._cache.move_to_end(episode_id)
                return self._cache[episode_id]
        source = self.episodes.source(episode_id, None)
        builder = self.make_builder(source.spec, episode_id)
        start = builder.start_message()
        steps = [builder.step(rec) for rec in source.records()]
        record = P.EpisodeRecord(start=start, steps=steps, end=builder.end_message(stopped=False))
        with self._lock:
            self._cache[episode_id] = record
            while len(self._cache) > CACHE_EPISODES:
                self._cache.popitem(last=False)
        return record
