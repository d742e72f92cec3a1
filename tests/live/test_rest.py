"""The REST reader: one worker, paced while an episode runs, bounded queue, finished episodes cached."""

from __future__ import annotations

import asyncio
import time

import pytest

from vlaprobe.live.rest import Busy, Reader


def work() -> float:
    time.sleep(0.1)
    return time.monotonic()


@pytest.mark.serial  # timed
def test_reads_are_serial_paced_while_live_and_bounded() -> None:
    live = [True]
    reader = Reader(None, None, live=lambda: live[0], duty=0.5, limit=2)

    async def main() -> None:
        t0 = time.monotonic()
        done = await asyncio.gather(reader.run(work), reader.run(work))
        # one worker: the second read starts after the first, then waits as long as it took (duty 0.5)
        paced = max(done) - t0
        assert min(done) - t0 >= 0.095 and paced >= 0.29
        results = await asyncio.gather(*(reader.run(work) for _ in range(3)), return_exceptions=True)
        assert sum(isinstance(r, Busy) for r in results) == 1  # the third waiting read is refused
        live[0] = False  # no episode: no pacing
        await asyncio.sleep(0.25)
        t1 = time.monotonic()
        done = await asyncio.gather(reader.run(work), reader.run(work))
        assert max(done) - t1 < paced  # no pause between them

    try:
        asyncio.run(main())
    finally:
        reader.close()


def test_listing_without_sources_is_empty() -> None:
    reader = Reader(None, None, live=lambda: False)
    try:
        assert reader.listing() == b"[]" and reader.episode("x") is None and reader.frame("x", 0) is None
    finally:
        reader.close()
