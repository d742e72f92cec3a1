"""The server's two security holes of issue 20, with the exact requests: reads outside the recordings folder and
DNS rebinding (a foreign Host header); recordings private to the server's user."""

from __future__ import annotations

import http.client
import json
import socket
import stat
from pathlib import Path

import pytest
from tests.live.fakes import SUCCESS_INIT, LiveServer, fake_app, local_client
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from vlaprobe.live.app import Limits
from vlaprobe.live.guard import Hosts, host_name

pytestmark = pytest.mark.timeout(60)


def get(port: int, path: str, host: str | None = None) -> tuple[int, bytes]:
    """GET ``path`` exactly as written (no normalisation, like ``curl --path-as-is``)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    conn.putrequest("GET", path, skip_host=host is not None)
    if host is not None:
        conn.putheader("Host", host)
    conn.endheaders()
    r = conn.getresponse()
    body = r.read()
    conn.close()
    return r.status, body


def record_one(tmp_path: Path) -> str:
    with local_client(fake_app(tmp_path)) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(json.dumps({"type": "start", "task": 0, "init": SUCCESS_INIT}))
        while (m := json.loads(ws.receive_text()))["type"] != "episode_end":
            pass
    return m["episode_id"]


def test_no_read_outside_the_recordings_folder(tmp_path: Path) -> None:
    # <recordings>/.. holds what a recording would: start.json and frames/000000.jpg (the bait)
    eid = record_one(tmp_path)
    real = tmp_path / "live" / eid
    (tmp_path / "start.json").write_bytes((real / "start.json").read_bytes())
    (tmp_path / "frames").mkdir()
    (tmp_path / "frames" / "000000.jpg").write_bytes(b"\xff\xd8secret")
    (tmp_path / "live" / "link").symlink_to(real)  # a symlink inside is not an id either
    with LiveServer(fake_app(tmp_path)) as srv:
        port = int(srv.http.rsplit(":", 1)[1])
        for path in (
            "/api/episodes/%2e%2e",
            "/api/episodes/%2e%2e/frames/0",
            "/api/episodes/..",
            "/api/episodes/../frames/0",
            "/api/episodes/%2E%2E%2Flive%2F" + eid,
            "/api/episodes/link",
            "/api/episodes/link/frames/0",
            "/api/episodes/.",
        ):
            status, body = get(port, path)
            assert status in (404, 422), (path, status)
            assert b"secret" not in body and b"episode_start" not in body
        assert get(port, f"/api/episodes/{eid}")[0] == 200
        assert get(port, f"/api/episodes/{eid}/frames/0")[0] == 200
        listed = json.loads(get(port, "/api/episodes")[1])
        assert [i["id"] for i in listed] == [eid]


def test_foreign_host_is_refused_for_rest_and_websocket(tmp_path: Path) -> None:
    with LiveServer(fake_app(tmp_path)) as srv:
        port = int(srv.http.rsplit(":", 1)[1])
        status, body = get(port, "/api/episodes", host=f"evil.example:{port}")
        assert status == 421 and body.count(b"\n") == 1
        assert get(port, "/", host=f"evil.example:{port}")[0] == 421
        for ok in (f"127.0.0.1:{port}", f"localhost:{port}", "localhost", f"[::1]:{port}"):
            assert get(port, "/api/episodes", host=ok)[0] == 200, ok
        # a page on evil.example, resolved to 127.0.0.1: Host and Origin both name evil.example
        sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        with pytest.raises(InvalidStatus) as exc:
            connect(f"ws://evil.example:{port}/ws", sock=sock, origin=f"http://evil.example:{port}")
        assert exc.value.response.status_code == 403
        with connect(srv.url, open_timeout=10) as ws:  # the server's own address still works
            assert json.loads(ws.recv(timeout=10))["type"] == "hello"


def test_origins_add_their_hosts(tmp_path: Path) -> None:
    limits = Limits(image_hz=1000.0, origins=("https://lab.example:8443",))
    with LiveServer(fake_app(tmp_path, limits)) as srv:
        port = int(srv.http.rsplit(":", 1)[1])
        assert get(port, "/api/episodes", host="lab.example:8443")[0] == 200
        assert get(port, "/api/episodes", host="other.example")[0] == 421


def test_host_names() -> None:
    assert host_name("Evil.Example.:80") == "evil.example" and host_name("[::1]:6006") == "::1"
    local = Hosts("127.0.0.1")
    assert local.allows("127.0.0.1:6006") and local.allows("localhost") and local.allows(None)
    assert not local.allows("192.168.1.5:6006") and not local.allows("evil.example")
    wildcard = Hosts("0.0.0.0")
    assert wildcard.allows("192.168.1.5:6006") and wildcard.allows("[fe80::1]:6006")
    assert not wildcard.allows("evil.example:6006")
    assert Hosts("10.0.0.7").allows("10.0.0.7:6006") and not Hosts("10.0.0.7").allows("10.0.0.8")


def test_recordings_are_private(tmp_path: Path) -> None:
    eid = record_one(tmp_path)
    folder = tmp_path / "live" / eid
    modes = {p.relative_to(folder).as_posix(): stat.S_IMODE(p.stat().st_mode) for p in folder.rglob("*")}
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700 and modes["frames"] == 0o700
    assert stat.S_IMODE((tmp_path / "live").stat().st_mode) == 0o700
    files = {k: v for k, v in modes.items() if k != "frames"}
    assert {"start.json", "steps.jsonl", "end.json", "frames/000000.jpg"} <= set(files)
    assert set(files.values()) == {0o600}
