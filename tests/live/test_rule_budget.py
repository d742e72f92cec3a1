"""`vlaprobe serve` and users' rules: a bad rules file is refused at start; SIGTERM stops the server in seconds,
even while a step's solve runs (real server processes on 127.0.0.1)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tests.cognition.test_rule_budget import PIGEONS, UNBOUNDED
from tests.live.fakes import SUCCESS_INIT, real_engine, serve_config
from websockets.sync.client import ClientConnection, connect

from vlaprobe.configs.monitor import CognitionConfig
from vlaprobe.errors import VlaprobeError

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT)]), "PYTHONUNBUFFERED": "1"}

SERVER = """
import socket, sys
from pathlib import Path
from tests.live.fakes import real_engine, serve_config
from vlaprobe.configs.monitor import CognitionConfig, RuleBudget
from vlaprobe.live.app import Limits, create_app
from vlaprobe.live.serve import run_server
run, rules = Path(sys.argv[1]), Path(sys.argv[2])
cognition = CognitionConfig(rules=(rules,), budget=RuleBudget(solve_seconds=600))
app = create_app(real_engine(serve_config(run, cognition=cognition)), Limits())
sock = socket.socket()
sock.bind(("127.0.0.1", 0))
print(sock.getsockname()[1], flush=True)
run_server(app, sock)
"""


def connect_when_up(port: int, proc: subprocess.Popen) -> ClientConnection:
    deadline = time.monotonic() + 60
    while True:
        try:
            return connect(f"ws://127.0.0.1:{port}/ws", open_timeout=30)
        except ConnectionRefusedError:  # the port is bound before uvicorn listens on it
            if time.monotonic() > deadline or proc.poll() is not None:
                raise
            time.sleep(0.2)


@pytest.mark.serial
def test_serve_refuses_an_unbounded_rule_at_start(fake_run: Path, tmp_path: Path) -> None:
    rules = tmp_path / "bad.lp"
    rules.write_text(UNBOUNDED)
    cmd = [sys.executable, "-m", "vlaprobe.cli", "serve", "--probes", str(fake_run / "probes"), "--port", "0"]
    cmd += ["--cognition.rules", str(rules), "--cognition.budget.ground-seconds", "2", "--device", "cpu"]
    done = subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=120)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "did not finish within 2 s: rule" in lines[0] and "n(X)" in lines[0]
    assert "vlaprobe live monitor" not in done.stdout


def test_the_engine_refuses_a_rules_file_not_utf8_before_any_episode(fake_run: Path, tmp_path: Path) -> None:
    rules = tmp_path / "bad.lp"
    rules.write_bytes(b"caf\xe9.\n")
    cfg = serve_config(fake_run, cognition=CognitionConfig(rules=(rules,)))
    with pytest.raises(VlaprobeError, match="is not UTF-8 text"):
        real_engine(cfg)


@pytest.mark.serial
@pytest.mark.timeout(180)
def test_sigterm_stops_the_server_within_seconds_while_a_solve_runs(fake_run: Path, tmp_path: Path) -> None:
    rules = tmp_path / "hard.lp"  # hard only once a belief has been true: the start check stays quick
    rules.write_text(
        PIGEONS.replace("hole(1..13).", "hole(1..13).\nbusy :- ever(B).").replace(
            ":- pigeon(P).", ":- pigeon(P), busy."
        )
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", SERVER, str(fake_run), str(rules)],
        cwd=ROOT,
        env=ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        port = int(proc.stdout.readline())
        with connect_when_up(port, proc) as ws:
            assert json.loads(ws.recv(timeout=30))["type"] == "hello"
            ws.send(json.dumps({"type": "start", "task": 0, "init": SUCCESS_INIT, "driver": "expert"}))
            time.sleep(3)  # the first step's solve is running now (its budget: 600 s)
            start = time.monotonic()
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(30)
        elapsed = time.monotonic() - start
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert elapsed < 10, elapsed
    assert code in (0, -signal.SIGTERM), proc.stderr.read()
