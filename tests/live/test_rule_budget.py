"""`vlaprobe serve` and users' rules: a bad rules file is refused at start; SIGTERM stops the server in seconds,
even while a step's solve runs (real server processes on 127.0.0.1)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tests.cognition.test_rule_budget import PIGEONS, UNBOUNDED
from tests.live.fakes import SUCCESS_INIT, real_engine, serve_config
from tests.live.process import ENV, connect_when_up, start_server, stop

from vlaprobe.configs.monitor import CognitionConfig
from vlaprobe.errors import VlaprobeError


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
    proc, port = start_server(fake_run, tmp_path / "live", tmp_path / "stderr", rules, solve_seconds=600)
    try:
        with connect_when_up(port, proc) as ws:
            assert json.loads(ws.recv(timeout=30))["type"] == "hello"
            ws.send(json.dumps({"type": "start", "task": 0, "init": SUCCESS_INIT, "driver": "expert"}))
            time.sleep(3)  # the first step's solve is running now (its budget: 600 s)
            start = time.monotonic()
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(30)
        elapsed = time.monotonic() - start
    finally:
        stop(proc)
    assert elapsed < 10, elapsed
    assert code in (0, -signal.SIGTERM), (tmp_path / "stderr").read_text()
