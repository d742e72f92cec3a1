"""The protocol through Starlette's test client: episodes, commands, errors, REST, recordings, security."""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect
from tests.live.fakes import FAIL_INIT, SUCCESS_INIT, episode_length, fake_app, fakes, local_client

from vlaprobe.live import protocol as P
from vlaprobe.live.app import Limits

pytestmark = pytest.mark.timeout(60)


def receive_until(ws: Any, kind: str, limit: int = 500) -> list[dict]:
    """Messages up to and including the first of type ``kind``."""
    out = []
    for _ in range(limit):
        msg = json.loads(ws.receive_text())
        out.append(msg)
        if msg.get("type") == kind:
            return out
    raise AssertionError(f"no {kind} in {limit} messages")


def start(task: int = 0, init: int = SUCCESS_INIT, **kw: Any) -> str:
    return json.dumps({"type": "start", "task": task, "init": init, **kw})


@pytest.fixture
def client(tmp_path: Path) -> Any:
    with local_client(fake_app(tmp_path)) as c:
        yield c


def test_hello_then_a_whole_episode_in_order(tmp_path: Path) -> None:
    # paced at 10 ms a step, so the client is caught up at every step (and gets every image) on a loaded machine
    # too: unpaced, the episode thread could run ahead of the sender and step 0 went out without its frame
    client = local_client(fake_app(tmp_path, step_seconds=0.01))
    with client, client.websocket_connect("/ws") as ws:
        hello = P.Hello.model_validate_json(ws.receive_text())
        assert hello.running is None and [t.index for t in hello.tasks] == [0, 1, 2]
        ws.send_text(start())
        msgs = receive_until(ws, "episode_end")
    start_msg = P.EpisodeStart.model_validate(msgs[0])
    steps = [P.Step.model_validate(m) for m in msgs[1:-1]]
    end = P.EpisodeEnd.model_validate(msgs[-1])
    n = episode_length(0, SUCCESS_INIT)
    assert [s.t for s in steps] == list(range(n)) and [s.step for s in steps] == list(range(n))
    assert start_msg.init == SUCCESS_INIT and start_msg.source == "live" and start_msg.subgoals
    assert end.success and end.steps == n and not end.stopped
    assert steps[-1].status == f"Task completed successfully in {n - 1} steps!"
    assert steps[0].status == "Executing step 0" and steps[-1].action is None
    assert len(steps[0].predicted.object.values) == len(start_msg.atoms.object)
    assert steps[0].truth is not None and steps[0].image  # caught-up client at 1000 Hz: every image
    assert all(s.episode_id == start_msg.episode_id for s in steps)
    # flips are the differences of consecutive predictions
    names = start_msg.atoms.object
    for a, b in itertools.pairwise(steps):
        pairs = zip(a.predicted.object.values, b.predicted.object.values, strict=True)
        on = {names[i] for i, (x, y) in enumerate(pairs) if y > x}
        assert on == {x for x in b.flips.predicted.on if x in names}


def test_second_start_is_refused_and_episode_goes_on(client: TestClient, tmp_path: Path) -> None:
    app_client = local_client(fake_app(tmp_path / "slow", step_seconds=0.05))
    with app_client, app_client.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(start(init=FAIL_INIT, max_steps=8))
        ws.send_text(start(init=FAIL_INIT))
        msgs = receive_until(ws, "episode_end")
    errors = [m for m in msgs if m["type"] == "error"]
    assert len(errors) == 1 and "is running" in errors[0]["message"]
    assert msgs[-1]["steps"] == 8 and not msgs[-1]["success"]
    assert msgs[-2]["status"] == "Task reached max steps (8 steps) without completion"


@pytest.mark.parametrize(
    ("frame", "needle"),
    [
        ("{not json", "invalid message"),
        ('{"type": "fly"}', "invalid message"),
        ('{"type": "start", "task": [1]}', "invalid message"),
        ('{"type": "start", "task": 0, "init": -1}', "init state"),
        ('{"type": "start", "task": 99}', "no task 99"),
        ('{"type": "start", "task": 0, "max_steps": 0}', "invalid message"),
        ('{"type": "stop"}', "no episode is running"),
        ("pick up the moon", "unknown task instruction"),
        ("   ", "empty message"),
        ('{"type": "replay", "episode_id": "x"}', "--store"),
    ],
)
def test_bad_frames_get_one_error_and_the_connection_stays_usable(
    client: TestClient, frame: str, needle: str
) -> None:
    with client.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(frame)
        msgs = receive_until(ws, "error", limit=50)
        assert needle in msgs[-1]["message"] and "\n" not in msgs[-1]["message"]
        ws.send_bytes(b"\x00\x01")
        assert "binary" in receive_until(ws, "error")[-1]["message"]
        ws.send_text(start())
        assert receive_until(ws, "episode_end")[-1]["success"]


def test_oversized_frame_closes_only_that_connection(client: TestClient) -> None:
    with client.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text("x" * 70_000)
        with pytest.raises(WebSocketDisconnect) as exc:
            ws.receive_text()
        assert exc.value.code == 1009
    with client.websocket_connect("/ws") as ws:
        assert json.loads(ws.receive_text())["type"] == "hello"


def test_paper_client_bare_instruction(client: TestClient) -> None:
    with client.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text("  PUT the bowl on the plate (0)  ")  # trimmed, any case
        msgs = receive_until(ws, "episode_end", limit=100)
    steps = [m for m in msgs if m["type"] == "step"]
    assert steps and all(isinstance(m["status"], str) and m["step"] == m["t"] for m in steps)
    assert all(isinstance(m["image"], str) and m["image"] for m in steps)
    assert msgs[0]["type"] == "episode_start" and msgs[0]["driver"] == "expert"


def test_stop_pause_resume_drop(tmp_path: Path) -> None:
    with local_client(fake_app(tmp_path, step_seconds=0.02)) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(start(init=FAIL_INIT, max_steps=30))
        receive_until(ws, "step")
        ws.send_text('{"type": "pause"}')
        ws.send_text('{"type": "drop", "steps": 3}')
        ws.send_text('{"type": "resume"}')
        ws.send_text('{"type": "stop"}')
        msgs = receive_until(ws, "episode_end")
        listed = c.get("/api/episodes").json()
    assert msgs[-1]["stopped"] and msgs[-1]["steps"] < 30
    assert [(e["success"], e["stopped"]) for e in listed] == [(False, True)]
    assert not [m for m in msgs if m["type"] == "error"]


def test_drop_is_announced_step_by_step(tmp_path: Path) -> None:
    """Each perturbed step says so, with the drop's steps still to come (the UI's drop indicator)."""
    with local_client(fake_app(tmp_path, step_seconds=0.02)) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(start(init=FAIL_INIT, max_steps=20))
        receive_until(ws, "step")
        ws.send_text('{"type": "drop", "steps": 3}')
        msgs = receive_until(ws, "episode_end")
    steps = [m for m in msgs if m["type"] == "step"]
    dropped = [(m["perturbed"], m["drop_left"]) for m in steps if m["perturbed"]]
    assert dropped == [(True, 2), (True, 1), (True, 0)]
    assert all(m["truth_progress"] is not None and m["truth_subgoals"] for m in steps)


def test_pause_is_announced_to_every_client_and_to_late_joiners(tmp_path: Path) -> None:
    with (
        local_client(fake_app(tmp_path, step_seconds=0.02)) as c,
        c.websocket_connect("/ws") as a,
        c.websocket_connect("/ws") as b,
    ):
        a.receive_text()
        b.receive_text()
        a.send_text(start(init=FAIL_INIT, max_steps=200))
        episode = receive_until(b, "step")[-1]["episode_id"]
        a.send_text('{"type": "pause"}')
        assert receive_until(b, "status")[-1] == {"type": "status", "episode_id": episode, "paused": True}
        assert receive_until(a, "status")[-1]["paused"] is True
        with c.websocket_connect("/ws") as late:
            hello = json.loads(late.receive_text())
            assert hello["running"] == {"episode_id": episode, "paused": True}
        b.send_text('{"type": "resume"}')
        assert receive_until(a, "status")[-1] == {"type": "status", "episode_id": episode, "paused": False}
        assert receive_until(b, "status")[-1]["paused"] is False
        with c.websocket_connect("/ws") as late:
            assert json.loads(late.receive_text())["running"]["paused"] is False
        a.send_text('{"type": "stop"}')
        receive_until(b, "episode_end")


def test_join_mid_episode_gets_history_first(tmp_path: Path) -> None:
    with local_client(fake_app(tmp_path, step_seconds=0.03)) as c, c.websocket_connect("/ws") as a:
        a.receive_text()
        a.send_text(start(init=FAIL_INIT, max_steps=20))
        receive_until(a, "step")
        receive_until(a, "step")
        with c.websocket_connect("/ws") as b:
            hello = json.loads(b.receive_text())
            assert hello["running"]["episode_id"]
            first = json.loads(b.receive_text())
            rest = receive_until(b, "episode_end")
        all_a = receive_until(a, "episode_end")
    assert first["type"] == "history" and first["steps"]
    assert all(s["image"] is None for s in first["steps"])
    joined = [s["t"] for s in first["steps"]] + [m["t"] for m in rest if m["type"] == "step"]
    assert joined == list(range(20)) and all_a[-1]["steps"] == 20


def test_rest_lists_and_serves_recordings_after_restart(tmp_path: Path) -> None:
    with local_client(fake_app(tmp_path)) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(start())
        msgs = receive_until(ws, "episode_end")
    eid = msgs[0]["episode_id"]
    with local_client(fake_app(tmp_path)) as c:  # a new server on the same recordings folder
        items = c.get("/api/episodes").json()
        assert [i["id"] for i in items] == [eid]
        assert items[0]["success"] is True and items[0]["steps"] == episode_length(0, SUCCESS_INIT)
        record = P.EpisodeRecord.model_validate(c.get(f"/api/episodes/{eid}").json())
        assert [s.t for s in record.steps] == list(range(items[0]["steps"]))
        assert record.end is not None and record.end.success
        live = [P.Step.model_validate(m) for m in msgs if m["type"] == "step"]
        assert [s.predicted for s in record.steps] == [s.predicted for s in live]
        frame = c.get(f"/api/episodes/{eid}/frames/0")
        assert frame.status_code == 200 and frame.content[:2] == b"\xff\xd8"
        assert c.get(f"/api/episodes/{eid}/frames/999").status_code == 404
        assert c.get("/api/episodes/..%2F..%2Fetc").status_code == 404
        assert c.get("/api/episodes/nope").status_code == 404


def test_token_and_origin(tmp_path: Path) -> None:
    limits = Limits(token="s3cret", image_hz=1000.0)
    with local_client(fake_app(tmp_path, limits)) as c:
        assert c.get("/api/episodes").status_code == 401
        assert c.get("/api/episodes?token=wrong").status_code == 401
        assert c.get("/api/episodes", headers={"Authorization": "Bearer s3cret"}).status_code == 200
        with pytest.raises(WebSocketDisconnect) as exc, c.websocket_connect("/ws") as ws:
            ws.receive_text()
        assert exc.value.code == 1008
        with c.websocket_connect("/ws?token=s3cret") as ws:
            assert json.loads(ws.receive_text())["type"] == "hello"
        evil = {"origin": "http://evil.example"}
        with pytest.raises(WebSocketDisconnect), c.websocket_connect("/ws?token=s3cret", headers=evil) as ws:
            ws.receive_text()
        ok = {"origin": "http://localhost:5173"}
        with c.websocket_connect("/ws?token=s3cret", headers=ok) as ws:
            assert json.loads(ws.receive_text())["type"] == "hello"


def test_ui_page_when_not_built(tmp_path: Path) -> None:
    with local_client(fake_app(tmp_path, Limits(ui=tmp_path / "none"))) as c:
        r = c.get("/")
    assert r.status_code == 200 and "not built" in r.text


def test_ui_folder_is_served(tmp_path: Path) -> None:
    ui = tmp_path / "ui"
    (ui / "assets").mkdir(parents=True)
    (ui / "index.html").write_text("<!doctype html><div id=root></div>")
    (ui / "assets" / "app.js").write_text("console.log(1)")
    with local_client(fake_app(tmp_path, Limits(ui=ui))) as c:
        assert "root" in c.get("/").text
        assert c.get("/assets/app.js").text == "console.log(1)"
        assert c.get("/api/episodes").status_code == 200


def test_fake_scene_is_the_collection_one() -> None:
    assert fakes.NUM_TASKS == 3
