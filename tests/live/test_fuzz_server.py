"""A fuzzer over the WebSocket's messages (hypothesis) against a real server process on 127.0.0.1.

Messages: every client command with its fields set to random values (wrong types, out of range, huge, unicode),
unknown types and fields, JSON that is not an object, text that is not JSON, binary frames and frames over the
size limit. After each message the client reads what came back for a moment; every few messages a liveness probe
(an unknown type) must be answered with an ``error`` within seconds. Counted: tracebacks on the server's stderr,
hangs (a probe unanswered), connections the server dropped (other than the 1009 of an oversized frame), the
server dying, and recorded episodes the REST API cannot read back (silent data loss).

CI runs a few dozen messages; ``VLAPROBE_FUZZ=big`` the sweep (``VLAPROBE_FUZZ_MESSAGES``, default 500;
``VLAPROBE_FUZZ_SEED`` fixes hypothesis's seed, default a fresh one) and ``VLAPROBE_FUZZ_REPORT=FILE`` writes the
counts as JSON.
"""

from __future__ import annotations

import json
import os
import time
import urllib.request
from pathlib import Path

import pytest
from tests.live.process import connect_when_up, start_server, stop
from websockets.exceptions import ConnectionClosed

hypothesis = pytest.importorskip("hypothesis")
st = pytest.importorskip("hypothesis.strategies")

BIG = os.environ.get("VLAPROBE_FUZZ") == "big"
MESSAGES = int(os.environ.get("VLAPROBE_FUZZ_MESSAGES", "500" if BIG else "40"))
SEED = int(os.environ["VLAPROBE_FUZZ_SEED"]) if os.environ.get("VLAPROBE_FUZZ_SEED") else None
PROBE_EVERY = 10
TYPES = ["start", "stop", "pause", "resume", "drop", "replay", "hello", "step", "", "START", "bogus"]
FIELDS = ["task", "init", "driver", "max_steps", "steps", "episode_id", "hz", "extra", "record"]

values = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.sampled_from([0, 1, 2, -1, 9, 10, 100, 10_000, 10_001, 4300 * "9"]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=40),
    st.sampled_from(["random", "expert", "policy", "dagger", "../../etc/passwd", "..", "store-t00_i00_a00"]),
    st.lists(st.integers(), max_size=3),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
)
commands = st.fixed_dictionaries({"type": st.sampled_from(TYPES)}, optional={f: values for f in FIELDS}).map(
    lambda d: json.dumps(d, allow_nan=True)
)  # NaN and Infinity: not JSON, sent anyway
valid = st.one_of(  # well-formed starts and replays, some out of range: episodes run between the junk
    st.fixed_dictionaries(
        {"type": st.just("start"), "task": st.integers(-1, 3)},
        optional={
            "init": st.one_of(st.integers(-1, 60), st.just("random")),
            "driver": st.sampled_from(["expert", "policy", "dagger"]),
            "max_steps": st.integers(0, 12),
        },
    ),
    st.fixed_dictionaries(
        {
            "type": st.just("replay"),
            "episode_id": st.from_regex(r"store-t0[0-3]_i0[0-9]_a00", fullmatch=True),
        },
        optional={"hz": st.sampled_from([0.1, 0.5, 60, 61, 1e9])},
    ),
).map(json.dumps)
frames = st.one_of(
    valid,
    valid,
    commands,
    commands,
    commands,
    st.text(max_size=200),
    st.binary(max_size=64),
    st.sampled_from(["", "null", "[]", "{", '{"type": null}', "x" * 70_000, '{"type":"start","task":0}']),
)


class Counts:
    def __init__(self) -> None:
        self.messages = self.hangs = self.dropped = self.oversized = self.errors = self.episodes = 0


def _drain(ws, seconds: float, counts: Counts) -> list[dict]:  # type: ignore[no-untyped-def]
    out = []
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        try:
            msg = json.loads(ws.recv(timeout=left))
        except TimeoutError:
            break
        out.append(msg)
        counts.errors += msg.get("type") == "error"
        counts.episodes += msg.get("type") == "episode_start"
    return out


def _alive(ws, counts: Counts) -> bool:  # type: ignore[no-untyped-def]
    ws.send('{"type": "liveness-probe"}')
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        for msg in _drain(ws, 1.0, counts):
            if msg.get("type") == "error" and "liveness-probe" in msg.get("message", ""):
                return True
    return False


def _unreadable_recordings(http: str) -> int:
    """Recorded live episodes that did not end (after every episode was stopped) or cannot be read back."""
    with urllib.request.urlopen(f"{http}/api/episodes", timeout=30) as r:
        episodes = [e for e in json.loads(r.read()) if e["source"] == "live"]
    bad = sum(e["success"] is None for e in episodes)
    for e in episodes:
        try:
            with urllib.request.urlopen(f"{http}/api/episodes/{e['id']}", timeout=30) as r:
                json.loads(r.read())
        except OSError:
            bad += 1
    return bad


@pytest.mark.serial
@pytest.mark.timeout(3600 if BIG else 300, method="thread")
def test_fuzzed_messages_leave_the_server_answering(fake_run: Path, tmp_path: Path) -> None:
    stderr = tmp_path / "stderr"
    proc, port = start_server(fake_run, tmp_path / "live", stderr)
    counts = Counts()
    state = {"ws": connect_when_up(port, proc, max_size=None)}
    hangs: list[str] = []

    @hypothesis.settings(
        max_examples=MESSAGES, deadline=None, database=None, derandomize=not BIG,
        phases=[hypothesis.Phase.generate], suppress_health_check=list(hypothesis.HealthCheck),
    )  # fmt: skip
    @hypothesis.seed(SEED)
    @hypothesis.given(frame=frames)
    def one(frame: str | bytes) -> None:
        ws = state["ws"]
        counts.messages += 1
        try:
            ws.send(frame)
            _drain(ws, 0.03, counts)
            if counts.messages % PROBE_EVERY == 0:
                ws.send('{"type": "stop"}')
                if not _alive(ws, counts):
                    hangs.append(repr(frame)[:200])
        except ConnectionClosed as exc:
            too_big = exc.rcvd is not None and exc.rcvd.code == 1009
            counts.oversized += too_big
            counts.dropped += not too_big
            state["ws"] = connect_when_up(port, proc, max_size=None)

    try:
        one()
        state["ws"].send('{"type": "stop"}')
        alive = _alive(state["ws"], counts)
        time.sleep(1)  # the stopped episode's end is written
        state["ws"].close()
        lost = _unreadable_recordings(f"http://127.0.0.1:{port}")
    finally:
        stop(proc)
    tracebacks = stderr.read_text().count("Traceback")
    report = {
        "messages": counts.messages, "seed": SEED, "tracebacks": tracebacks, "hangs": len(hangs), "dropped": counts.dropped,
        "oversized_closed_1009": counts.oversized, "error_replies": counts.errors,
        "episodes_started": counts.episodes, "unreadable_recordings": lost, "alive_at_end": alive,
    }  # fmt: skip
    if os.environ.get("VLAPROBE_FUZZ_REPORT"):
        Path(os.environ["VLAPROBE_FUZZ_REPORT"]).write_text(json.dumps(report) + "\n")
    print(json.dumps(report))
    assert alive and not hangs and tracebacks == 0 and counts.dropped == 0 and lost == 0, (report, hangs)
    assert counts.messages >= MESSAGES
