"""`vlaprobe serve --takeover alarm` on LIBERO: in a live episode on 127.0.0.1 the tiny model acts, the alarm
(a low stall threshold) fires on the predictions and the scripted expert's actions are executed for
--takeover-steps steps (--takeover-until steps; the subgoal's hand-back on LIBERO:
tests/rollout/test_takeover_libero.py), then the model's again; every message matches the exported schema (slow: libero mark).
Random probes and random model weights: the plumbing, not what the probes know."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from tests.live import test_live_libero
from tests.live.fakes import LiveServer
from tests.live.test_takeover import check_schema, takeovers_of
from websockets.sync.client import connect

from vlaprobe.configs.serve import ServeConfig
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.live.app import create_app
from vlaprobe.live.serve import build_engine, limits_of, load_probes

pytestmark = [pytest.mark.libero, pytest.mark.timeout(600), pytest.mark.heavy]
STEPS, TAKEOVER_STEPS = 16, 4
probes = test_live_libero.probes
"""The fixture: random probes over task 0's atoms."""


def test_the_alarm_hands_a_live_libero_episode_to_the_expert(probes: Path, tmp_path: Path) -> None:
    cfg = ServeConfig(
        probes=probes,
        model="tiny",
        device="cpu",
        recordings=tmp_path,
        driver="policy",
        intervention=TakeoverConfig(
            takeover="alarm",
            takeover_stall=2,
            takeover_steps=TAKEOVER_STEPS,
            takeover_most=2,
            takeover_until="steps",
        ),
    )
    app = create_app(build_engine(cfg, load_probes(cfg)), limits_of(cfg, None))
    with LiveServer(app) as srv, connect(srv.url, max_size=None) as ws:
        hello = json.loads(ws.recv(timeout=30))
        ws.send(json.dumps({"type": "start", "task": 0, "init": 0, "driver": "policy", "max_steps": STEPS}))
        msgs = []
        while not msgs or msgs[-1]["type"] not in ("episode_end", "error"):
            msgs.append(json.loads(ws.recv(timeout=120)))
    for m in [hello, *msgs]:
        check_schema(m)
    assert hello["takeover"]["mode"] == "alarm" and msgs[-1]["type"] == "episode_end"
    steps = msgs[1:-1]
    fired = [s["t"] for s in steps if s["alarm"] is not None]
    taken = takeovers_of(steps)
    assert fired and taken, "no alarm in the episode: the test proves nothing"
    assert [start for start, _, _ in taken] == [t + 1 for t in fired if t + 1 < len(steps) - 1]
    expert_rows = {s["t"] for s in steps if s["takeover"] is not None}
    for s in steps[:-1]:  # the terminal row has no action
        executed, model = np.array(s["action"]), np.array(s["predicted_action"])
        if s["t"] in expert_rows:
            assert not np.allclose(executed, model), s["t"]  # the scripted expert's action, not the model's
        else:
            assert np.allclose(executed, model), s["t"]
    assert all(n == TAKEOVER_STEPS for start, n, _ in taken if start + TAKEOVER_STEPS < len(steps) - 1)
    assert msgs[-1]["summary"]["expert_steps"] == len(expert_rows)
