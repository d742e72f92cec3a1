"""The server on a real uvicorn (127.0.0.1 only) with websockets clients: episodes, fuzz, churn, leaks."""

from __future__ import annotations

import asyncio
import json
import random
import threading
import time
from pathlib import Path

import pytest
from tests.live.fakes import FAIL_INIT, SUCCESS_INIT, LiveServer, episode_length, fake_app
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from vlaprobe.live import protocol as P

pytestmark = pytest.mark.timeout(120)


def messages_until(ws, kind: str, limit: int = 5000, timeout: float = 30) -> list[dict]:
    out = []
    for _ in range(limit):
        msg = json.loads(ws.recv(timeout=timeout))
        out.append(msg)
        if msg["type"] == kind:
            return out
    raise AssertionError(f"no {kind}")


def test_episode_end_to_end_on_uvicorn(tmp_path: Path) -> None:
    with LiveServer(fake_app(tmp_path)) as srv, connect(srv.url, open_timeout=10) as ws:
        hello = json.loads(ws.recv(timeout=10))
        assert hello["type"] == "hello" and hello["suite"] == "libero_spatial"
        ws.send(json.dumps({"type": "start", "task": 0, "init": SUCCESS_INIT, "driver": "expert"}))
        msgs = messages_until(ws, "episode_end")
    steps = [m for m in msgs if m["type"] == "step"]
    assert msgs[0]["type"] == "episode_start" and msgs[0]["suite"] == "libero_spatial"  # recorded with it too
    assert [m["t"] for m in steps] == list(range(episode_length(0, SUCCESS_INIT)))
    assert msgs[-1]["success"] is True


def is_valid(text: str) -> bool:
    try:
        P.CLIENT.validate_json(text)
    except ValueError:
        return False
    return True


def test_fuzz_does_not_disturb_another_clients_episode(tmp_path: Path) -> None:
    rng = random.Random(0)
    valid = ['{"type":"start","task":0}', '{"type":"pause"}', '{"type":"stop"}', '{"type":"drop"}']
    junk = [
        "",
        "{",
        "null",
        "[]",
        '{"type": 5}',
        '{"type":"start","task":{"a":1}}',
        '{"type":"start","task":0,"init":"x"}',
        '{"type":"start","task":0,"extra":1}',
        '{"type":"replay","episode_id":"../../etc/passwd"}',
        "\udcff".encode("utf-8", "surrogatepass").decode("utf-8", "replace"),
        "pick up the black bowl" * 50,
        # issue 20: int() after isdigit() dropped the connection; a replay's wait could block for 1000 s
        "²",
        "①",
        "9" * 4301,
        "9" * 5000,
        "0" * 4400,
        '{"type":"start","task":"²"}',
        '{"type":"start","task":"①","init":0}',
        '{"type":"replay","episode_id":"store-t00_i00_a00","hz":0.001}',
        '{"type":"replay","episode_id":"..","hz":10}',
        '{"type":"drop","steps":0}',
        '{"type":"start","task":0,"max_steps":20000}',
    ]

    def frame() -> str | bytes:
        kind = rng.random()
        if kind < 0.15:
            return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
        if kind < 0.3:
            s = rng.choice(valid)
            i = rng.randrange(len(s))
            return s[:i] + rng.choice('{}[]",:x0 ') + s[i + 1 :]
        if kind < 0.4:
            return "".join(chr(rng.randrange(32, 0x2FFF)) for _ in range(rng.randrange(1, 200)))
        return rng.choice(junk)

    with LiveServer(fake_app(tmp_path, step_seconds=0.01)) as srv, connect(srv.url) as owner:
        owner.recv(timeout=10)
        owner.send(json.dumps({"type": "start", "task": 0, "init": FAIL_INIT, "max_steps": 120}))
        result: dict = {}

        def follow() -> None:
            result["msgs"] = messages_until(owner, "episode_end", timeout=60)

        t = threading.Thread(target=follow)
        t.start()
        errors = suppressed = sent = 0
        with connect(srv.url, max_size=None) as fuzzer:
            fuzzer.recv(timeout=10)
            for f in [*junk, *(frame() for _ in range(1000))]:
                if isinstance(f, str) and is_valid(f):
                    continue  # a command that stops or pauses the episode on purpose is not a malformed frame
                fuzzer.send(f)
                sent += 1
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline:
                try:
                    m = json.loads(fuzzer.recv(timeout=2))
                except TimeoutError:
                    break
                if m["type"] == "error" and "more errors suppressed" in m["message"]:
                    suppressed += int(m["message"].split()[0])
                elif m["type"] == "error":
                    errors += 1
                    assert "\n" not in m["message"]
            fuzzer.send("   ")  # the fuzzer's connection is still open and answered
            assert "empty message" in json.loads(fuzzer.recv(timeout=10))["message"]
        t.join(60)
        with connect(srv.url) as again:  # the server still answers
            assert json.loads(again.recv(timeout=10))["type"] == "hello"
    msgs = result["msgs"]
    assert msgs[-1]["type"] == "episode_end" and msgs[-1]["steps"] == 120 and not msgs[-1]["stopped"]
    assert [m["t"] for m in msgs if m["type"] == "step"] == list(range(120))
    assert errors + suppressed == sent and errors >= 32  # one reply per bad frame, or counted (docs/live.md)


def test_connect_churn_leaks_nothing(tmp_path: Path) -> None:
    with LiveServer(fake_app(tmp_path, step_seconds=0.01)) as srv, connect(srv.url) as owner:
        owner.recv(timeout=10)
        base_tasks = srv.in_loop(lambda: len(asyncio.all_tasks()))
        # 400 steps: the episode outlasts the 50 connects on a loaded machine
        owner.send(json.dumps({"type": "start", "task": 0, "init": FAIL_INIT, "max_steps": 400}))
        for i in range(50):
            with connect(srv.url) as ws:
                ws.recv(timeout=10)
                if i % 3 == 0:
                    ws.recv(timeout=10)  # some read a message, some leave at once
                if i % 4 == 1:  # vanish in the middle of a frame: header says 4 KiB, 100 bytes sent
                    ws.socket.sendall(b"\x81\xfe\x10\x00" + b"mask" + b"x" * 100)
                if i % 2:
                    ws.socket.close()  # vanish without a close frame
        msgs = messages_until(owner, "episode_end", timeout=60)
        deadline = time.monotonic() + 10
        while srv.in_loop(lambda: len(srv.app.state.hub.clients)) > 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert srv.in_loop(lambda: len(srv.app.state.hub.clients)) == 1
        assert srv.in_loop(lambda: len(asyncio.all_tasks())) <= base_tasks
    assert msgs[-1]["steps"] == 400


def test_oversized_frame_closes_with_1009(tmp_path: Path) -> None:
    with LiveServer(fake_app(tmp_path), max_size=1000) as srv:
        with connect(srv.url, max_size=None) as ws:
            ws.recv(timeout=10)
            ws.send("x" * 5000)
            with pytest.raises(ConnectionClosed) as exc:
                ws.recv(timeout=10)
            assert exc.value.rcvd is not None and exc.value.rcvd.code == 1009
        with connect(srv.url) as ws:
            assert json.loads(ws.recv(timeout=10))["type"] == "hello"
