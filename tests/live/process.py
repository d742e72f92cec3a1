"""`vlaprobe serve`'s server (``run_server``) in a real process on 127.0.0.1: the real engine (probes, cognition,
recorder, store replays) over the fake simulator and model, for signal and fuzz tests."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from websockets.sync.client import ClientConnection, connect

ROOT = Path(__file__).resolve().parents[2]
ENV = {
    **os.environ,
    "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT), os.environ.get("PYTHONPATH", "")]),
    "PYTHONUNBUFFERED": "1",
}
SERVER = """
import dataclasses, socket, sys
from pathlib import Path
from tests.live.fakes import real_engine, serve_config
from vlaprobe.configs.monitor import CognitionConfig, RuleBudget
from vlaprobe.live.app import Limits, create_app
from vlaprobe.live.serve import run_server
run, recordings, rules, solve = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], float(sys.argv[4])
cognition = CognitionConfig(rules=(Path(rules),) if rules else (), budget=RuleBudget(solve_seconds=solve))
cfg = serve_config(run, cognition=cognition, store=run / "activations")
cfg = dataclasses.replace(cfg, recordings=recordings)
app = create_app(real_engine(cfg), Limits(image_hz=1000.0, replay_hz=60.0))
sock = socket.socket()
sock.bind(("127.0.0.1", 0))
print(sock.getsockname()[1], flush=True)
run_server(app, sock)
"""


def start_server(
    run: Path, recordings: Path, stderr: Path, rules: Path | None = None, solve_seconds: float = 2.0
) -> tuple[subprocess.Popen, int]:
    """The server process on the fake run folder (``activations/``, ``probes/``) and its port; its stderr goes
    to the file ``stderr``."""
    with open(stderr, "w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-c", SERVER, str(run), str(recordings), str(rules or ""), str(solve_seconds)],
            cwd=ROOT,
            env=ENV,
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
        )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.strip():
        proc.wait(30)
        raise RuntimeError(f"the server did not start: {stderr.read_text()[-2000:]}")
    return proc, int(line)


def connect_when_up(port: int, proc: subprocess.Popen, **kw: object) -> ClientConnection:
    """A WebSocket client of the server (the port is bound before uvicorn listens on it: retried)."""
    deadline = time.monotonic() + 60
    while True:
        try:
            return connect(f"ws://127.0.0.1:{port}/ws", open_timeout=30, **kw)  # type: ignore[arg-type]
        except ConnectionRefusedError:
            if time.monotonic() > deadline or proc.poll() is not None:
                raise
            time.sleep(0.2)


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
