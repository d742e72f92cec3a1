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
from vlaprobe.live.takeover import LiveTakeovers
from vlaprobe.rollout.takeover import Takeover

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
        takeover_until="steps",
    )
    assert hello["protocol"] == 5 and hello["drivers"] == ["policy"]
    assert hello["takeover"] == {
        **{
            "mode": "alarm",
            "steps": 3,
            "until": "steps",
            "most": 2,
            "stall": 4,
            "hold": 5,
            "count": 1,
            "on": ["stall", "regression", "dropped", "violation"],
        }
    }
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
    assert {t["ended"] for t in end["summary"]["takeovers"]} <= {"steps", None}
    for start_row, n, _ in taken:  # the expert acts its steps, then the policy again
        under = [s["t"] for s in steps if s["takeover"] and s["takeover"]["start"] == start_row]
        assert under == list(range(start_row, start_row + n))
        assert steps[start_row + n]["handover"] == "to_policy" and steps[start_row + n]["takeover"] is None
        assert all(s["alarm"] is None for s in steps[start_row : start_row + n])  # silent while it acts


def test_until_subgoal_a_takeover_the_subgoal_does_not_end_stops_at_its_cap(
    fake_run: Path, tmp_path: Path
) -> None:
    # The fake probes' predictions never mark a subgoal done: every takeover runs to its cap (the subgoal's
    # hand-back itself: test_the_live_hand_back_asks_for_the_policy_once_the_subgoal_is_done).
    hello, msgs = episode(
        fake_run,
        tmp_path,
        {"init": FAIL_INIT, "max_steps": 60},
        takeover="alarm",
        takeover_stall=4,
        takeover_steps=20,
        takeover_most=3,
    )
    assert hello["takeover"]["until"] == "subgoal" and hello["takeover"]["steps"] == 20
    steps, summary = msgs[1:-1], msgs[-1]["summary"]["takeovers"]
    assert len(summary) >= 2, "fewer than two takeovers: the test proves little"
    for t in summary:
        last = t["start"] + t["steps"] - 1
        assert t["ended"] in ("cap", None) and (t["steps"] == 20) == (t["ended"] == "cap"), t
        if t["ended"] is None:  # the episode ended while the expert acted
            assert last >= len(steps) - 2, t
        if t["ended"] == "cap":  # the step messages say so from the takeover's last step on
            assert steps[last]["takeover"]["ended"] == "cap" and steps[last - 1]["takeover"]["ended"] is None
            assert steps[last + 1]["handover"] == "to_policy"


def test_the_live_hand_back_asks_for_the_policy_once_the_subgoal_is_done() -> None:
    from types import SimpleNamespace

    from tests.cognition.test_alarm import _level

    live = LiveTakeovers(TakeoverConfig(takeover="alarm", takeover_stall=100), seed=0, max_steps=50)
    under = Takeover(2, "stall: x")
    backs = []
    for t, (done, by) in enumerate([(0, None), (0, None), (1, under), (1, under), (2, under), (2, None)]):
        live.observe(SimpleNamespace(t=t, takeover=by, terminal=False), _level(t, done))  # type: ignore[arg-type]
        backs.append(live.take_hand_back())
    assert backs == [None, None, None, None, "subgoal: grasped(a)", None]
    steps = LiveTakeovers(TakeoverConfig(takeover="alarm", takeover_until="steps"), seed=0, max_steps=50)
    steps.observe(SimpleNamespace(t=4, takeover=under, terminal=False), _level(4, 2))  # type: ignore[arg-type]
    assert steps.take_hand_back() is None  # a fixed length: nobody hands back


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
