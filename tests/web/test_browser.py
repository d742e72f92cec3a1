"""End to end in a real browser: `vlaprobe serve` (tiny model, LIBERO, the cognition) and the web UI in Debian's
chromium, driven by Playwright. The UI starts a task, streams frames, marks a flip, is scrubbed back while the
episode runs and returns to live, drops the object and shows it, ends the episode; the timeline is scrubbed
(mouse, keyboard, raster click), the focused beliefs view and its disagreement filter are checked, axe-core's
contrast rule runs on the page, the recording is replayed and a store episode re-run; every step shown is
compared with the server's record. Then the server restarts and the page must reconnect by itself and list the
recording again. Screenshots go to test-output/browser/ (random probes: noisier than trained ones, so the
docs/live.md's docs/img/live-view.png is made with trained probes by `python -m tests.web.browser`, see docs/web.md).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
import torch
from tests.web.browser import CHROMIUM, run_browser
from tests.web.checks import AXE

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "test-output" / "browser"

pytestmark = [
    pytest.mark.libero,
    pytest.mark.serial,  # a browser, a server and the simulator: timed waits
    pytest.mark.timeout(900),
    pytest.mark.skipif(
        not CHROMIUM.exists(), reason="needs Debian's chromium at /usr/bin/chromium (apt install chromium)"
    ),
]


def make_tiny_probes(folder: Path) -> None:
    """Random linear probes for the tiny model on LIBERO-spatial's atoms, in `vlaprobe train`'s format.

    Random weights read the tiny model's hidden states: predictions change with the frames, so flips happen;
    every seventh atom is left unprobed (held at a majority value), as training does for near-constant atoms.
    """
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.envs import make_env
    from vlaprobe.policies import make_policy
    from vlaprobe.probes.probemeta import HeadMeta, ProbesMeta
    from vlaprobe.probes.probeset import ProbeSet
    from vlaprobe.probes.results import DroppedAtom
    from vlaprobe.symbols.vocabulary import build_vocabulary

    policy = make_policy(PolicyConfig("tiny", device="cpu"))
    env = make_env(0, EnvConfig())
    try:
        vocab = build_vocabulary(env.scene)
    finally:
        env.close()
    hidden_size = int(policy.hidden_size)
    num_hidden_states = int(policy.num_hidden_states)
    layers = [num_hidden_states - 1]
    g = torch.Generator().manual_seed(0)
    tensors, heads = {}, {}
    for head, atoms in (("object", vocab.object_atoms), ("action", vocab.action_atoms)):
        kept = [a for i, a in enumerate(atoms) if i % 7 != 6]
        dropped = [DroppedAtom(a, 0.0, "constant") for a in atoms if a not in kept]
        tensors[f"{head}.weight"] = torch.randn(1, hidden_size, len(kept), generator=g) / hidden_size**0.5
        tensors[f"{head}.bias"] = torch.zeros(1, len(kept))
        heads[head] = HeadMeta(
            atom_names=list(atoms),
            kept=kept,
            kept_index=[atoms.index(a) for a in kept],
            dropped=dropped,
            best_layer=layers[0],
            best_metric="accuracy",
        )
    meta = ProbesMeta(
        model_id=policy.model_id,
        pooling=policy.pooling,
        hidden_size=hidden_size,
        num_hidden_states=num_hidden_states,
        layers=layers,
        threshold=0.5,
        heads=heads,
        standardized=False,
    )
    ProbeSet(meta, tensors).save(folder)


def collect_store(folder: Path) -> None:
    """One short stored episode of task 0 (the tiny model watching the expert), for the store re-run."""
    from vlaprobe.collection.collect import collect
    from vlaprobe.configs.collect import CollectConfig
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.configs.policy import PolicyConfig

    cfg = CollectConfig(
        out=folder, tasks=(0,), episodes_per_task=1, max_tries_per_task=1, keep_failed=True, progress=False,
        env=EnvConfig(max_steps=12), policy=PolicyConfig(model="tiny"),
    )  # fmt: skip
    collect(cfg)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Serve:
    """`vlaprobe serve` with the tiny model on 127.0.0.1 as a subprocess; restartable on the same port."""

    def __init__(self, tmp: Path) -> None:
        self.tmp, self.port = tmp, free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None
        self.log_path = tmp / "serve.log"
        self.extra: list[str] = []
        """More options of the server (``restart(extra)`` changes them)."""

    def start(self, timeout_s: float = 240) -> None:
        cmd = [
            str(Path(sys.executable).with_name("vlaprobe")),
            "serve",
            "--probes", str(self.tmp / "probes"),
            "--recordings", str(self.tmp / "live"),
            "--store", str(self.tmp / "store"),
            "--host", "127.0.0.1",
            "--port", str(self.port),
            "--model", "tiny",
            *self.extra,
        ]  # fmt: skip
        with open(self.log_path, "a") as log:
            self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
        deadline = time.monotonic() + timeout_s
        while True:
            if self.proc.poll() is not None:
                pytest.fail(
                    f"vlaprobe serve exited ({self.proc.returncode}): {self.log_path.read_text()[-2000:]}"
                )
            try:
                with urllib.request.urlopen(self.base + "/api/episodes", timeout=2):
                    return
            except OSError:
                if time.monotonic() > deadline:
                    pytest.fail(f"vlaprobe serve did not come up: {self.log_path.read_text()[-2000:]}")
                time.sleep(0.5)

    def stop(self) -> None:
        if self.proc is None:
            return
        self.proc.terminate()
        try:
            self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.proc = None

    def restart(self, extra: list[str] | None = None) -> None:
        self.stop()
        if extra is not None:
            self.extra = extra
        self.start()


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory):
    """A running `vlaprobe serve` on random tiny-model probes."""
    tmp = tmp_path_factory.mktemp("serve")
    make_tiny_probes(tmp / "probes")
    collect_store(tmp / "store")
    srv = Serve(tmp)
    try:
        srv.start()
        yield srv
    finally:
        srv.stop()


def test_live_episode_timeline_replay_and_reconnect_in_chromium(server: Serve) -> None:
    assert AXE.is_file(), f"axe-core is missing ({AXE}): run `cd web && npm ci`"
    if OUT.exists():
        shutil.rmtree(OUT)
    takeover = ["--driver", "policy", "--takeover", "alarm", "--takeover-stall", "2", "--takeover-steps", "4"]
    run = run_browser(
        server.base,
        OUT,
        max_steps=30,
        min_steps=10,
        episode_timeout_s=240,
        restart=server.restart,
        takeover=lambda: server.restart(takeover),
    )
    assert run.distinct_frames >= 10, run.distinct_frames
    assert run.saw_turned_on, "no atom was shown as just turned true"
    assert len(run.checked_steps) >= 5
    assert run.reconnected, "the page did not reconnect after the server restarted"
    assert run.scrubbed_live, "the slider was not scrubbed back during the live episode"
    assert run.second_tab_synced, "a second tab did not show the running episode's settings"
    assert "forced open" in run.drop_text and "left" in run.drop_text, run.drop_text
    assert run.contrast == [], run.contrast
    assert run.tabs_to_timeline is not None and run.tabs_to_timeline <= 5
    assert run.two_columns_at_1024, "the beliefs collapse to one column at 1024 px"
    assert run.rerun_frames >= 10, run.rerun_frames
    assert run.focus["pinned"] > 0 and run.focus["differing"] > 0, run.focus
    assert len(run.takeover_steps) == 2, "the takeover panel was not checked"
    assert not run.console_errors, run.console_errors
    for name in (
        "live-view.png",
        "timeline.png",
        "timeline-greyscale.png",
        "layout-1024.png",
        "takeover.png",
    ):
        assert (OUT / name).stat().st_size > 10_000, name
