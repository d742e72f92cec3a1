"""Live episodes of a suite whose tasks have different objects: the probes' union atoms, undefined ones marked.

The fake simulator gives task 1 one more object (a cup) than task 0; the probes are over the union of the two
tasks' atoms, as probes trained on a union store are. Task 0's episode leaves the cup's atoms undefined exactly
as a replay of its stored episode would (``episode_start.defined``, null probabilities, never true).
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from tests.collection.fakes import HIDDEN, LAYERS, SCENE, FakeEnv
from tests.collection.test_collect_union import CUP_SCENE
from tests.live.fakes import SUCCESS_INIT, LiveServer, local_client, random_probes, real_engine

from vlaprobe.configs.serve import ServeConfig
from vlaprobe.envs.suite_vocabulary import union_vocabulary
from vlaprobe.live import protocol as P
from vlaprobe.live.app import Limits, create_app
from vlaprobe.symbols import HEADS, build_vocabulary

pytestmark = pytest.mark.timeout(120)


def app_of(folder: Path, scenes: list) -> object:
    """The real engine over the fake simulator, with random probes over the union of ``scenes``' atoms."""
    vocab = union_vocabulary(scenes)
    atoms = {h: list(vocab.atoms(h)) for h in HEADS}
    probes = random_probes(folder / "probes", "fake", LAYERS, HIDDEN, atoms, layer=2)
    cfg = ServeConfig(probes=probes, recordings=folder / "live")
    return create_app(real_engine(cfg), Limits(image_hz=1000.0))


@pytest.fixture
def union_app(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> object:
    monkeypatch.setattr(FakeEnv, "SCENES", {1: CUP_SCENE})
    return app_of(tmp_path / "union", [SCENE, CUP_SCENE])


def run_episode(app: object, task: int) -> tuple[dict, P.EpisodeStart, list[P.Step]]:
    with local_client(app) as c, c.websocket_connect("/ws") as ws:
        hello = json.loads(ws.receive_text())
        ws.send_text(json.dumps({"type": "start", "task": task, "init": SUCCESS_INIT, "driver": "expert"}))
        msgs = []
        while not msgs or msgs[-1]["type"] != "episode_end":
            msgs.append(json.loads(ws.receive_text()))
    start = P.EpisodeStart.model_validate(msgs[0])
    return hello, start, [P.Step.model_validate(m) for m in msgs[1:-1]]


def test_live_episode_marks_the_atoms_its_task_lacks(union_app: object, tmp_path: Path) -> None:
    hello, start, steps = run_episode(union_app, 0)
    _, own_start, own_steps = run_episode(app_of(tmp_path / "own", [SCENE]), 0)  # probes of task 0's atoms
    assert own_start.defined is None and len(own_steps) == len(steps)
    assert hello["protocol"] == P.PROTOCOL_VERSION == 5
    own = build_vocabulary(SCENE)
    assert start.defined is not None and steps
    for h in HEADS:
        names = getattr(start.atoms, h)
        assert names == hello["probes"]["atoms"][h]  # the probes' (union) atoms
        defined = getattr(start.defined, h)
        assert defined == [a in own.atoms(h) for a in names]  # undefined: the cup's atoms
        undefined = ~np.array(defined)
        probed = np.array(getattr(start.probed, h))
        assert (undefined & probed).any()  # the probes read some of them: their numbers are withheld
        for s in steps:
            pred, truth = getattr(s.predicted, h), np.array(getattr(s.truth, h), bool)
            probs = np.array([p is not None for p in pred.probs])
            assert (probs == (probed & ~undefined)).all()  # null: not probed, or undefined
            assert not np.array(pred.values, bool)[undefined].any() and not truth[undefined].any()
        # the task's own labels sit in their columns of the union (as collection widens them)
        columns = [names.index(a) for a in getattr(own_start.atoms, h)]
        wide = np.array([getattr(s.truth, h) for s in steps])
        assert (wide[:, columns] == np.array([getattr(s.truth, h) for s in own_steps])).all()
        assert wide[:, columns].any()
    believed = {b for s in steps for b in s.beliefs.asserted}
    assert not any("cup" in b for b in believed)
    assert "cup" not in " ".join(v for s in steps for v in s.flips.predicted.on)


def test_live_episode_of_the_task_with_every_object_defines_every_atom(union_app: object) -> None:
    _, start, steps = run_episode(union_app, 1)
    assert start.defined is None and steps  # null: every atom is defined
    cup = [i for i, a in enumerate(start.atoms.object) if "cup" in a]
    assert any(s.predicted.object.probs[i] is not None for s in steps for i in cup)


@pytest.mark.skipif(not (shutil.which("javac") and shutil.which("java")), reason="no JDK (javac, java) found")
def test_java_client_receives_the_undefined_atoms(union_app: object, tmp_path: Path) -> None:
    """The DIARC client on a real server on 127.0.0.1 hears of the atoms task 0 lacks, and believes none."""
    client = Path(__file__).resolve().parents[2] / "clients" / "diarc" / "src"
    sources = sorted(str(p) for p in client.rglob("*.java"))
    subprocess.run(["javac", "-d", str(tmp_path / "classes"), *sources], check=True, timeout=120)
    with LiveServer(union_app) as srv:
        start = ["--start", "0", "--init", str(SUCCESS_INIT), "--once"]
        run = subprocess.run(
            ["java", "-cp", str(tmp_path / "classes"), "vlaprobe.diarc.LiveClient", srv.url, *start],
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert run.returncode == 0, run.stderr
    vocab, own = union_vocabulary([SCENE, CUP_SCENE]), build_vocabulary(SCENE)
    lacking = [a for h in HEADS for a in vocab.atoms(h) if a not in own.atoms(h)]
    lines = run.stdout.splitlines()
    defined = sum(len(own.atoms(h)) for h in HEADS)
    assert f"ATOMS defined={defined} undefined={len(lacking)}" in lines
    assert f"UNDEFINED {' '.join(lacking)}" in lines
    believed = next(line for line in lines if line.startswith("BELIEFS")).split()[1:]
    assert believed and not any("cup" in b for b in believed)


def test_a_task_with_atoms_the_probes_lack_is_refused_in_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(FakeEnv, "SCENES", {1: CUP_SCENE})
    app = app_of(tmp_path, [SCENE])  # probes of task 0's atoms: task 1's cup is not among them
    with local_client(app) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(json.dumps({"type": "start", "task": 1, "init": 0}))
        reply = json.loads(ws.receive_text())
    assert reply["type"] == "error" and "\n" not in reply["message"]
    assert (
        "cup" in reply["message"]
        and "serve probes trained on a store that holds this task" in reply["message"]
    )
