"""`vlaprobe serve --takeover`: the alarm on the predictions hands the policy's control to the expert, the messages
say so (checked against the exported JSON Schema), on the real engine over the fake simulator and model."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from tests.live.fakes import FAIL_INIT, local_client, real_engine

from vlaprobe.configs.serve import ServeConfig
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.live import protocol as P
from vlaprobe.live.app import Limits, create_app

pytestmark = pytest.mark.timeout(120)
SERVER = jsonschema.Draft202012Validator({**json.loads(P.SCHEMA_FILE.read_text()), "required": ["server"]})
"""protocol.schema.json (the file, as clients read it), for one server message."""


def check_schema(message: dict) -> None:
    SERVER.validate({"server": message})


def episode(run: Path, tmp: Path, start: dict, **takeover: Any) -> tuple[dict, list[dict]]:
    """The hello and every message of one episode of a server with ``--takeover``."""
    cfg = ServeConfig(
        probes=run / "probes",
        recordings=tmp / "live",
        driver="policy",
        intervention=TakeoverConfig(**takeover),
    )
    app = create_app(real_engine(cfg), Limits(image_hz=1000.0))
    with local_client(app) as c, c.websocket_connect("/ws") as ws:
        hello = json.loads(ws.receive_text())
        ws.send_text(json.dumps({"type": "start", "task": 0, "driver": "policy", **start}))
        msgs: list[dict] = []
        while not msgs or msgs[-1]["type"] not in ("episode_end", "error"):
            msgs.append(json.loads(ws.receive_text()))
    for m in [hello, *msgs]:
        check_schema(m)
    return hello, msgs


def takeovers_of(steps: list[dict]) -> list[tuple[int, int, str]]:
    """(start, steps, reason) of each takeover, read from the steps' fields."""
    out: dict[int, tuple[int, int, str]] = {}
    for s in steps:
        if (t := s["takeover"]) is not None:
            out[t["index"]] = (t["start"], t["steps"], t["reason"])
    return [out[i] for i in sorted(out)]


def test_the_alarm_hands_the_policy_to_the_expert_and_back(fake_run: Path, tmp_path: Path) -> None:
    hello, msgs = episode(
        fake_run,
        tmp_path,
        {"init": FAIL_INIT, "max_steps": 30},
        takeover="alarm",
        takeover_stall=4,
        takeover_steps=3,
        takeover_most=2,
    )
    assert hello["protocol"] == 3 and hello["drivers"] == ["policy"]
    assert hello["takeover"] == {"mode": "alarm", "steps": 3, "most": 2, "stall": 4, "hold": 5, "count": 1}
    start, steps, end = msgs[0], msgs[1:-1], msgs[-1]
    assert start["takeover"] == "alarm" and end["type"] == "episode_end"
    alarms = [s for s in steps if s["alarm"] is not None]
    assert alarms, "the alarm never fired: the test proves nothing"
    assert len(alarms) <= 2
    for a in alarms:
        kind, reason = a["alarm"]["kind"], a["alarm"]["reason"]
        after = steps[a["t"] + 1]
        assert after["handover"] == "to_expert" and after["takeover"]["start"] == a["t"] + 1
        assert after["takeover"]["reason"] == f"{kind}: {reason}" and after["takeover"]["steps"] == 1
        if kind == "stall":
            assert a["alarm"]["atoms"] and "no subgoal done" in reason
    taken = takeovers_of(steps)
    assert [(t["start"], t["steps"], t["reason"]) for t in end["summary"]["takeovers"]] == taken
    assert end["summary"]["expert_steps"] == sum(n for _, n, _ in taken) == 3 * len(taken)
    for start_row, n, _ in taken:  # the expert acts its steps, then the policy again
        under = [s["t"] for s in steps if s["takeover"] and s["takeover"]["start"] == start_row]
        assert under == list(range(start_row, start_row + n))
        assert steps[start_row + n]["handover"] == "to_policy" and steps[start_row + n]["takeover"] is None
        assert all(s["alarm"] is None for s in steps[start_row : start_row + n])  # silent while it acts


def test_the_random_control_takes_over_at_its_count(fake_run: Path, tmp_path: Path) -> None:
    hello, msgs = episode(
        fake_run,
        tmp_path,
        {"init": FAIL_INIT, "max_steps": 40},
        takeover="random",
        takeover_steps=4,
        takeover_count=2,
    )
    steps = msgs[1:-1]
    assert hello["takeover"]["mode"] == "random" and all(s["alarm"] is None for s in steps)
    taken = takeovers_of(steps)
    assert len(taken) == 2 and {r for _, _, r in taken} == {"random"}
    assert msgs[-1]["summary"]["expert_steps"] == sum(n for _, n, _ in taken)


def test_an_expert_start_is_refused_on_a_takeover_server(fake_run: Path, tmp_path: Path) -> None:
    cfg = ServeConfig(
        probes=fake_run / "probes",
        recordings=tmp_path / "live",
        driver="policy",
        intervention=TakeoverConfig(takeover="alarm"),
    )
    with local_client(create_app(real_engine(cfg), Limits())) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(json.dumps({"type": "start", "task": 0, "driver": "expert"}))
        err = json.loads(ws.receive_text())
    assert err["type"] == "error" and "start with driver 'policy'" in err["message"]


def test_without_takeover_the_fields_are_empty(fake_run: Path, tmp_path: Path) -> None:
    hello, msgs = episode(fake_run, tmp_path, {"init": FAIL_INIT, "max_steps": 12})
    assert hello["takeover"] is None and hello["drivers"] == ["expert", "policy"]
    assert msgs[0]["takeover"] == "none" and msgs[-1]["summary"]["takeovers"] == []
    assert all(s["alarm"] is None and s["takeover"] is None for s in msgs[1:-1])
