"""Issue 20's server crashes, hangs and misleading answers: each gets one ``error`` to its sender (the
connection kept) or a one-line 4xx, and episodes start, stop and end as asked."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Any

import pytest
from tests.live.fakes import FAIL_INIT, SUCCESS_INIT, LiveServer, fake_app, local_client, real_engine
from websockets.sync.client import connect

from vlaprobe.configs.serve import ServeConfig
from vlaprobe.live.app import Limits, create_app

pytestmark = pytest.mark.timeout(120)


def until(ws: Any, kind: str, limit: int = 2000) -> list[dict]:
    out = []
    for _ in range(limit):
        out.append(json.loads(ws.receive_text()))
        if out[-1]["type"] == kind:
            return out
    raise AssertionError(f"no {kind}")


def start(**kw: Any) -> str:
    return json.dumps({"type": "start", "task": 0, "init": SUCCESS_INIT, **kw})


@pytest.mark.parametrize(
    ("frame", "needle"),
    [
        ("²", "unknown task instruction"),
        ("①", "unknown task instruction"),
        ("9" * 4301, "unknown task instruction"),
        ("9" * 5000, "unknown task instruction"),
        ("0" * 4400, "unknown task instruction"),
        ('{"type":"start","task":"²"}', "unknown task instruction"),
        ('{"type":"start","task":0,"max_steps":3000}', "more than the simulator runs"),
        ('{"type":"start","task":0,"init":999}', "no init state 999"),
        ('{"type":"replay","episode_id":"store-t00_i00_a00","hz":0.001}', "replay.hz"),
        ('{"type":"replay","episode_id":"store-t00_i00_a00","hz":1000}', "replay.hz"),
    ],
)
def test_frames_that_crashed_get_one_error(fake_run: Path, tmp_path: Path, frame: str, needle: str) -> None:
    with local_client(real_app(fake_run, tmp_path)) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(frame)
        msg = until(ws, "error")[-1]["message"]
        assert needle in msg and "\n" not in msg and len(msg) < 600
        ws.send_text(start())  # the connection is kept and works
        assert until(ws, "episode_end")[-1]["success"]


def real_app(run: Path, tmp: Path, **limits: Any) -> Any:
    cfg = ServeConfig(probes=run / "probes", store=run / "activations", recordings=tmp / "live")
    return create_app(real_engine(cfg), Limits(image_hz=1000.0, **limits))


@pytest.mark.serial  # timed: the stop within 1 s
def test_stop_interrupts_a_slow_replay(fake_run: Path, tmp_path: Path) -> None:
    with local_client(real_app(fake_run, tmp_path)) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        eid = next(i["id"] for i in c.get("/api/episodes").json() if i["source"] == "store")
        ws.send_text(json.dumps({"type": "replay", "episode_id": eid, "hz": 0.5}))  # 2 s per step
        until(ws, "step")
        t0 = time.monotonic()
        ws.send_text('{"type": "stop"}')
        end = until(ws, "episode_end")[-1]
        assert end["stopped"] and time.monotonic() - t0 < 1.0
        ws.send_text(start())  # the episode thread is free again
        assert until(ws, "episode_end")[-1]["success"]


def test_damaged_store_is_refused_with_the_repair(fake_run: Path, tmp_path: Path) -> None:
    from vlaprobe.errors import VlaprobeError

    store = tmp_path / "activations"
    shutil.copytree(fake_run / "activations", store)
    key = sorted(p.name for p in (store / "episodes").iterdir() if p.is_dir())[0]
    chunk = next(
        p for p in (store / "episodes" / key / "hidden").rglob("*") if p.is_file() and p.name != "zarr.json"
    )
    chunk.write_bytes(b"garbage, not a zstd frame" * 4)  # present and non-empty: only decoding finds it
    cfg = ServeConfig(probes=fake_run / "probes", store=store, recordings=tmp_path / "live")
    with local_client(create_app(real_engine(cfg), Limits(image_hz=1000.0))) as c:
        r = c.get(f"/api/episodes/store-{key}")
        assert r.status_code == 422
        detail = r.json()["detail"]
        assert "damaged" in detail and "vlaprobe collect" in detail and str(tmp_path) not in detail
        assert c.get(f"/api/episodes/store-{key}/frames/0").status_code == 422
        with c.websocket_connect("/ws") as ws:
            ws.receive_text()
            ws.send_text(json.dumps({"type": "replay", "episode_id": f"store-{key}"}))
            assert "damaged" in until(ws, "error")[-1]["message"]
    chunk.unlink()  # a missing chunk: found before the server starts
    with pytest.raises(VlaprobeError, match="delete them"):
        real_engine(cfg)


def test_damaged_recordings_serve_what_is_readable(tmp_path: Path) -> None:
    with local_client(fake_app(tmp_path)) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        ids = []
        for _ in range(3):
            ws.send_text(start())
            ids.append(until(ws, "episode_end")[-1]["episode_id"])
    live = tmp_path / "live"
    lines = (live / ids[0] / "steps.jsonl").read_text().splitlines(keepends=True)
    lines[1] = '{"t": 1, "cut'[:9] + "\n"  # a corrupt middle line
    (live / ids[0] / "steps.jsonl").write_text("".join(lines))
    start_json = (live / ids[1] / "start.json").read_text()
    (live / ids[1] / "start.json").write_text(start_json[: len(start_json) // 2])  # truncated
    (live / ids[2] / "end.json").write_text("{broken")
    with local_client(fake_app(tmp_path)) as c:
        listed = {i["id"]: i for i in c.get("/api/episodes").json()}
        assert set(listed) == {ids[0], ids[2]} and listed[ids[2]]["success"] is None
        first = c.get(f"/api/episodes/{ids[0]}")
        assert first.status_code == 200
        assert [s["t"] for s in first.json()["steps"]] == [i for i in range(len(lines)) if i != 1]
        r = c.get(f"/api/episodes/{ids[1]}")
        assert r.status_code == 422 and "start.json" in r.json()["detail"]
        assert str(tmp_path) not in r.json()["detail"]
        third = c.get(f"/api/episodes/{ids[2]}").json()
        assert third["end"] is None and third["steps"]


def test_recordings_folder_replaced_by_a_file_names_no_path(tmp_path: Path) -> None:
    with (
        local_client(fake_app(tmp_path, step_seconds=0.02)) as c,
        c.websocket_connect("/ws") as a,
        c.websocket_connect("/ws") as b,
    ):
        a.receive_text()
        b.receive_text()
        a.send_text(start(init=FAIL_INIT, max_steps=200))
        until(a, "step")
        (tmp_path / "live").rename(tmp_path / "moved")
        (tmp_path / "live").write_text("a file now")
        errors = [m for m in until(b, "episode_end") if m["type"] == "error"]
        assert errors and all("/" not in e["message"] for e in errors)
        assert str(tmp_path) not in json.dumps(errors)
        (tmp_path / "live").unlink()
        until(a, "episode_end")
        a.send_text(start())  # the server goes on
        assert until(a, "episode_end")[-1]["success"]


def test_start_right_after_episode_end_and_a_stop_with_it(tmp_path: Path) -> None:
    with local_client(fake_app(tmp_path)) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(start(init=FAIL_INIT, max_steps=3))
        old = until(ws, "episode_end")[-1]["episode_id"]
        for _ in range(15):
            ws.send_text(start(init=FAIL_INIT, max_steps=400))
            ws.send_text('{"type": "stop"}')
            msgs = until(ws, "episode_end")
            assert not [m for m in msgs if m["type"] == "error"], msgs
            assert msgs[0]["type"] == "episode_start" and msgs[0]["episode_id"] != old
            assert msgs[-1]["episode_id"] == msgs[0]["episode_id"] and msgs[-1]["stopped"]
            assert msgs[-1]["steps"] < 400
            old = msgs[-1]["episode_id"]


def test_errors_go_to_the_sender_only(tmp_path: Path) -> None:
    app = fake_app(tmp_path)  # its simulator learns the init states only when it builds the task
    with local_client(app) as c, c.websocket_connect("/ws") as a, c.websocket_connect("/ws") as b:
        a.receive_text()
        b.receive_text()
        a.send_text(start(init=999))
        assert "no init state 999" in until(a, "error")[-1]["message"]
        b.send_text("   ")
        assert "empty message" in json.loads(b.receive_text())["message"]  # b got nothing in between
        a.send_text(start())
        assert until(b, "episode_end")[-1]["success"]


def test_unread_bad_frames_are_counted_not_lost(tmp_path: Path) -> None:
    with LiveServer(fake_app(tmp_path)) as srv, connect(srv.url) as ws:
        ws.recv(timeout=10)
        for i in range(500):
            ws.send(f"not a task {i}")
        errors, suppressed = 0, 0
        while True:
            try:
                msg = json.loads(ws.recv(timeout=2))
            except TimeoutError:
                break
            assert msg["type"] == "error"
            if "more errors suppressed" in msg["message"]:
                suppressed += int(msg["message"].split()[0])
            else:
                errors += 1
        assert errors + suppressed == 500 and errors >= 32
