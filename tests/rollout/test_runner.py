"""The episode runner's pieces that need no simulator: the environment cache and paced replays."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import pytest

from vlaprobe.rollout import EnvCache, EpisodeControl, paced


class _Env(SimpleNamespace):
    def close(self) -> None:
        self.closed = True


def test_the_cache_keeps_one_environment_and_rebuilds_on_a_new_task() -> None:
    built: list[int] = []
    cache = EnvCache(
        lambda task: _Env(task_index=task, closed=False), on_new=lambda task, env: built.append(task)
    )
    first = cache.get(3)
    assert cache.get(3) is first and built == [3]
    second = cache.get(4)
    assert first.closed and not second.closed and built == [3, 4] and cache.builds == 2
    cache.close()
    assert second.closed and cache.env is None


@pytest.mark.serial  # timed
def test_paced_obeys_stop_and_pause_between_records() -> None:
    control = EpisodeControl()
    seen = []
    for r in paced(range(10), control):  # type: ignore[arg-type]
        seen.append(r)
        if r == 2:
            control.stop()
    assert seen == [0, 1, 2]
    control = EpisodeControl()
    control.pause()
    threading.Timer(0.2, control.resume).start()
    t0 = time.monotonic()
    assert list(paced(range(2), control)) == [0, 1]  # type: ignore[arg-type]
    assert time.monotonic() - t0 >= 0.15


@pytest.mark.serial  # timed
def test_paced_keeps_the_rate() -> None:
    t0 = time.monotonic()
    assert list(paced(range(4), None, hz=20.0)) == [0, 1, 2, 3]  # type: ignore[arg-type]
    assert 0.12 <= time.monotonic() - t0 < 2.0  # three intervals of 50 ms
