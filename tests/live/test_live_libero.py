"""The real thing: `vlaprobe serve` on LIBERO with the tiny model and the scripted expert (slow: libero mark).

The probes here have random weights of the tiny model's shapes: these tests check the plumbing (every step in
order, success, the drop perturbation seen by the cognition on the true atoms), not what the probes know.
"""

from __future__ import annotations

import base64
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import simplejpeg
from tests.live.fakes import LiveServer, random_probes
from websockets.sync.client import connect

from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.serve import ServeConfig
from vlaprobe.live.app import create_app
from vlaprobe.live.serve import build_engine, limits_of, load_probes

pytestmark = [pytest.mark.libero, pytest.mark.timeout(600), pytest.mark.serial]  # the CLI starts in < 30 s
MAX_STEPS = 220  # the expert needs ~100-200 steps; the paper allowed 220


@pytest.fixture(scope="module")
def probes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from vlaprobe.envs.libero import LiberoTaskEnv

    env = LiberoTaskEnv(0, EnvConfig())
    vocab = env.labeler.vocabulary
    env.close()
    atoms = {"object": list(vocab.object_atoms), "action": list(vocab.action_atoms)}
    return random_probes(tmp_path_factory.mktemp("run") / "probes", "tiny-openvla-seed0", 33, 64, atoms)


@pytest.fixture(scope="module")
def server(probes: Path, tmp_path_factory: pytest.TempPathFactory) -> LiveServer:
    cfg = ServeConfig(probes=probes, model="tiny", device="cpu", recordings=tmp_path_factory.mktemp("live"))
    app = create_app(build_engine(cfg, load_probes(cfg)), limits_of(cfg, None))
    with LiveServer(app) as srv:
        yield srv


def follow(ws, on_step=None, timeout: float = 120) -> list[dict]:
    msgs = []
    while not msgs or msgs[-1]["type"] != "episode_end":
        msgs.append(json.loads(ws.recv(timeout=timeout)))
        if on_step is not None and msgs[-1]["type"] == "step":
            on_step(msgs[-1])
    return msgs


def test_expert_episode_streams_every_step_then_success(server: LiveServer) -> None:
    with connect(server.url, max_size=None) as ws:
        hello = json.loads(ws.recv(timeout=30))
        assert hello["model_id"] == "tiny-openvla-seed0" and len(hello["tasks"]) == 10
        ws.send(
            json.dumps({"type": "start", "task": 0, "init": 0, "driver": "expert", "max_steps": MAX_STEPS})
        )
        msgs = follow(ws)
    steps = [m for m in msgs if m["type"] == "step"]
    assert msgs[0]["type"] == "episode_start" and len(msgs[0]["atoms"]["object"]) == len(
        steps[0]["truth"]["object"]
    )
    assert [m["t"] for m in steps] == list(range(len(steps)))
    assert msgs[-1]["success"] is True and msgs[-1]["steps"] == len(steps)
    assert steps[-1]["status"].startswith("Task completed successfully")
    assert any(e["kind"] == "goal_reached" for s in steps for e in s["truth_events"])
    assert steps[0]["image"] and steps[5]["timings"]["model_ms"] > 0


def test_drop_raises_the_regression_event(server: LiveServer) -> None:
    state = {"grasped_at": None, "dropped_at": None}
    with connect(server.url, max_size=None) as ws:
        json.loads(ws.recv(timeout=30))
        ws.send(
            json.dumps({"type": "start", "task": 0, "init": 0, "driver": "expert", "max_steps": MAX_STEPS})
        )
        seen: list[dict] = []

        def on_step(m: dict) -> None:
            if state["grasped_at"] is None and any(
                e["kind"] == "subgoal_done" and "grasped" in e["message"] for e in m["truth_events"]
            ):
                state["grasped_at"] = m["t"]
            elif (
                state["grasped_at"] is not None
                and state["dropped_at"] is None
                and m["t"] >= state["grasped_at"] + 12
            ):
                ws.send(json.dumps({"type": "drop", "steps": 12}))  # in mid-air, on the way to the plate
                state["dropped_at"] = m["t"]
            seen.extend(e for e in m["truth_events"] if e["kind"] in ("regression", "dropped"))
            if seen and state["dropped_at"] is not None:
                ws.send('{"type": "stop"}')

        msgs = follow(ws, on_step)
    assert state["dropped_at"] is not None, "the expert never grasped the bowl"
    # A second episode on the same simulator still renders (not black: the GL context stays on its thread).
    image = simplejpeg.decode_jpeg(base64.b64decode(next(m["image"] for m in msgs if m.get("image"))))
    assert image.mean() > 30
    assert seen and seen[0]["t"] > state["dropped_at"]
    assert msgs[-1]["stopped"] or not msgs[-1]["success"]


def test_cli_starts_in_seconds_and_prints_the_address(probes: Path, tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", "vlaprobe.cli", "serve", "--probes", str(probes), "--port", "0"]
    cmd += ["--recordings", str(tmp_path / "live"), "--device", "cpu", "--model", "tiny"]
    start = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = proc.stdout.readline()
        elapsed = time.monotonic() - start
    finally:
        proc.terminate()
        proc.wait(30)
    assert line.startswith("vlaprobe live monitor: http://127.0.0.1:"), proc.stderr.read()
    assert elapsed < 30


def test_the_trained_default_drives_live(probes: Path, tmp_path: Path) -> None:
    """`vlaprobe serve --driver policy` path: tiny-libero's own actions step the simulator, every step streamed."""
    from vlaprobe.probes.probemeta import read_probes_meta, write_probes_meta

    meta = read_probes_meta(probes)
    meta.model_id = "tiny-libero"
    own = tmp_path / "probes"
    own.mkdir()
    for f in probes.iterdir():
        (own / f.name).write_bytes(f.read_bytes())
    write_probes_meta(own, meta)
    cfg = ServeConfig(probes=own, device="cpu", driver="policy", recordings=tmp_path / "live")
    assert cfg.model == "tiny-libero"  # the shipped default observer
    app = create_app(build_engine(cfg, load_probes(cfg)), limits_of(cfg, None))
    with LiveServer(app) as srv, connect(srv.url, max_size=None) as ws:
        assert json.loads(ws.recv(timeout=30))["model_id"] == "tiny-libero"
        ws.send(json.dumps({"type": "start", "task": 3, "init": 44, "driver": "policy", "max_steps": 25}))
        msgs = follow(ws)
    steps = [m for m in msgs if m["type"] == "step"]
    assert [m["t"] for m in steps] == list(range(25)) and msgs[-1]["steps"] == 25
    assert all(m["timings"]["model_ms"] > 0 for m in steps[1:])
    acted = [m for m in steps if m["action"] is not None]
    assert len(acted) >= 24 and all(m["predicted_action"] is not None for m in acted)
    # The executed action is the model's own (the gripper dimension as LIBERO takes it: +-1).
    for m in acted:
        assert m["action"][:6] == pytest.approx(m["predicted_action"][:6], abs=1e-5)
    assert len({tuple(np.round(m["action"][:6], 4)) for m in acted}) > 1  # not a constant action
