"""Fan-out: a slow client loses no step state, gets only the newest images, and never holds up another."""

from __future__ import annotations

import asyncio
import itertools
import json
import time

import pytest

from vlaprobe.live.hub import Hub

pytestmark = pytest.mark.timeout(30)


class Sink:
    """A client connection; ``gate`` closed = the client reads nothing."""

    def __init__(self, open_: bool = True) -> None:
        self.received: list[dict] = []
        self.times: list[float] = []
        self.gate = asyncio.Event()
        if open_:
            self.gate.set()

    async def send_text(self, data: str) -> None:
        await self.gate.wait()
        self.received.append(json.loads(data))
        self.times.append(time.monotonic())

    async def close(self, code: int = 1000, reason: str | None = None) -> None:
        self.closed_with = code


def state(t: int) -> str:
    return json.dumps({"type": "step", "episode_id": "e", "t": t})


async def run_episode(hub: Hub, steps: int) -> None:
    hub.begin("e", json.dumps({"type": "episode_start", "episode_id": "e"}))
    for t in range(steps):
        hub.step(state(t), f"img{t}")
        for _ in range(10):  # a producer slower than the senders (a simulator step is ~100 ms)
            await asyncio.sleep(0)
    hub.end(json.dumps({"type": "episode_end", "episode_id": "e"}))


def test_slow_client_gets_every_state_and_only_the_newest_image() -> None:
    async def main() -> tuple[Sink, Sink, Hub]:
        hub = Hub(asyncio.get_running_loop())
        fast, slow = Sink(), Sink(open_=False)
        cf, cs = hub.add(fast, 1e6), hub.add(slow, 1e6)
        tasks = [asyncio.create_task(hub.run_sender(c)) for c in (cf, cs)]
        await run_episode(hub, 500)
        for _ in range(20000):
            await asyncio.sleep(0)
            if fast.received and fast.received[-1]["type"] == "episode_end":
                break
        # the fast client finished while the slow one reads nothing
        assert fast.received[-1]["type"] == "episode_end"
        assert len(slow.received) == 0
        memory = len(hub.current.states)  # one shared log, whatever the clients' speed
        assert memory == 500
        slow.gate.set()
        for _ in range(20000):
            await asyncio.sleep(0)
            if slow.received and slow.received[-1]["type"] == "episode_end":
                break
        for c in (cf, cs):
            hub.remove(c)
        await asyncio.gather(*tasks)
        return fast, slow, hub

    fast, slow, hub = asyncio.run(main())
    for sink in (fast, slow):
        steps = [m for m in sink.received if m["type"] == "step"]
        assert [m["t"] for m in steps] == list(range(500))
    assert sum(m["image"] is not None for m in fast.received if m["type"] == "step") == 500
    slow_images = [m["t"] for m in slow.received if m["type"] == "step" and m["image"] is not None]
    assert slow_images == [499]  # intermediate images dropped: the newest wins
    assert not hub.clients


def test_image_rate_is_capped_per_client() -> None:
    async def main() -> Sink:
        hub = Hub(asyncio.get_running_loop())
        sink = Sink()
        c = hub.add(sink, 10.0)
        task = asyncio.create_task(hub.run_sender(c))
        hub.begin("e", json.dumps({"type": "episode_start", "episode_id": "e"}))
        for t in range(30):  # 30 steps over ~0.6 s at 50 steps/s
            hub.step(state(t), f"img{t}")
            await asyncio.sleep(0.02)
        hub.end(json.dumps({"type": "episode_end", "episode_id": "e"}))
        await asyncio.sleep(0.05)
        hub.remove(c)
        await task
        return sink

    sink = asyncio.run(main())
    steps = [m for m in sink.received if m["type"] == "step"]
    sent = [when for m, when in zip(sink.received, sink.times, strict=True) if m.get("image") is not None]
    assert len(steps) == 30 and len(sent) >= 3  # every state, some images
    assert min(b - a for a, b in itertools.pairwise(sent)) >= 0.099  # at most 10 per second


def test_a_client_joining_mid_episode_gets_history_then_the_rest() -> None:
    async def main() -> Sink:
        hub = Hub(asyncio.get_running_loop())
        hub.begin("e", json.dumps({"type": "episode_start", "episode_id": "e"}))
        for t in range(5):
            hub.step(state(t), f"img{t}")
        sink = Sink()
        c = hub.add(sink, 1e6)
        task = asyncio.create_task(hub.run_sender(c))
        await asyncio.sleep(0)
        for t in range(5, 8):
            hub.step(state(t), f"img{t}")
            await asyncio.sleep(0)
        hub.end(json.dumps({"type": "episode_end", "episode_id": "e"}))
        await asyncio.sleep(0.01)
        hub.remove(c)
        await task
        return sink

    got = asyncio.run(main()).received
    assert got[0]["type"] == "history" and [s["t"] for s in got[0]["steps"]] == [0, 1, 2, 3, 4]
    assert got[0]["start"]["type"] == "episode_start"
    assert [m["t"] for m in got[1:-1]] == [5, 6, 7] and got[-1]["type"] == "episode_end"


def test_a_client_that_reads_nothing_for_too_long_is_closed_and_forgotten() -> None:
    async def main() -> tuple[Sink, Hub, object]:
        hub = Hub(asyncio.get_running_loop(), send_timeout=0.2)
        dead, live = Sink(open_=False), Sink()
        cd, cl = hub.add(dead, 1e6), hub.add(live, 1e6)
        tasks = [asyncio.create_task(hub.run_sender(c)) for c in (cd, cl)]
        await run_episode(hub, 20)
        await asyncio.sleep(0.5)
        hub.remove(cl)
        await asyncio.gather(*tasks)
        return dead, hub, cd

    dead, hub, client = asyncio.run(main())
    assert dead.closed_with == 1008 and client.log is None and not hub.clients
