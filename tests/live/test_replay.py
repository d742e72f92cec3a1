"""The real readout and cognition behind the server: store replays equal `vlaprobe cognition`, live uses them too."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import numpy as np
import pytest
from tests.live.fakes import SUCCESS_INIT, local_client, real_engine

from vlaprobe.cognition.monitor import monitor
from vlaprobe.cognition.readout import ProbeReadout
from vlaprobe.collection.store import ActivationStore
from vlaprobe.configs.monitor import MonitorConfig
from vlaprobe.configs.serve import ServeConfig
from vlaprobe.live import protocol as P
from vlaprobe.live.app import Limits, create_app

pytestmark = pytest.mark.timeout(120)


def real_app(run: Path, tmp: Path, **kw: object) -> object:
    cfg = ServeConfig(probes=run / "probes", store=run / "activations", recordings=tmp / "live", **kw)
    engine = real_engine(cfg)
    return create_app(engine, Limits(image_hz=1000.0, replay_hz=500.0))


def test_store_replay_equals_monitor(fake_run: Path, tmp_path: Path) -> None:
    store = ActivationStore.open(fake_run / "activations")
    readout = ProbeReadout.load(fake_run / "probes")
    figures = {
        e.key: e
        for e in monitor(
            MonitorConfig(
                store=fake_run / "activations", probes=fake_run / "probes", all_episodes=True, out=tmp_path
            )
        ).per_episode
    }
    with local_client(real_app(fake_run, tmp_path)) as c:
        items = [i for i in c.get("/api/episodes").json() if i["source"] == "store"]
        assert {i["id"] for i in items} == {"store-" + e.key for e in store.episodes()}
        for item in items:
            key = item["id"].removeprefix("store-")
            record = P.EpisodeRecord.model_validate(c.get(f"/api/episodes/{item['id']}").json())
            assert record.start.source == "store" and len(record.steps) == item["steps"]
            assert record.start.store_episode == item["id"] and record.start.goal_objects
            assert all(s.truth_subgoals and s.truth_progress is not None for s in record.steps)
            assert record.end.summary.success_step == (
                next((s.t for s in record.steps if "successfully" in s.status), None)
            )
            rows = {h: store.layer(readout.layers[h], [key]) for h in ("object", "action")}
            expected = readout.assign_steps(rows)
            for h in ("object", "action"):
                got = np.array([getattr(s.predicted, h).values for s in record.steps], bool)
                assert (got == expected.values[h]).all()
            truth = np.array([s.truth.object for s in record.steps], bool)
            assert (truth == store.labels("object", [key])).all()
            f = figures[key]
            assert record.end.summary.goal_step_predicted == f.goal_step_probes
            assert record.end.summary.goal_step_truth == f.goal_step_truth
            assert sum(record.end.summary.violations.values()) == f.violations_probes
            frame = c.get(f"/api/episodes/{item['id']}/frames/0")
            assert frame.status_code == 200 and frame.headers["content-type"] == "image/jpeg"


def test_replay_streams_over_the_websocket(fake_run: Path, tmp_path: Path) -> None:
    with local_client(real_app(fake_run, tmp_path)) as c, c.websocket_connect("/ws") as ws:
        hello = json.loads(ws.receive_text())
        assert hello["model_id"] == "fake" and any(not p for p in hello["probes"]["probed"]["object"])
        eid = c.get("/api/episodes").json()[0]["id"]
        rest = c.get(f"/api/episodes/{eid}").json()
        ws.send_text(json.dumps({"type": "replay", "episode_id": eid}))
        msgs = []
        while not msgs or msgs[-1]["type"] != "episode_end":
            msgs.append(json.loads(ws.receive_text()))
        ws.send_text('{"type": "drop"}')
        assert "no episode is running" in json.loads(ws.receive_text())["message"]
    steps = [m for m in msgs if m["type"] == "step"]
    assert msgs[0]["source"] == "store" and len(steps) == len(rest["steps"])
    assert msgs[0]["store_episode"] == eid != msgs[0]["episode_id"]  # the re-run's frames are the store's
    # The episode's not-probed atoms are the probes' dropped ones: null probabilities in every step.
    for h in ("object", "action"):
        assert msgs[0]["probed"][h] == hello["probes"]["probed"][h]
        assert [p is not None for p in steps[0]["predicted"][h]["probs"]] == msgs[0]["probed"][h]
    assert [s["predicted"] for s in steps] == [s["predicted"] for s in rest["steps"]]
    assert not (tmp_path / "live").exists() or not any(
        (tmp_path / "live").iterdir()
    )  # replays are not recorded


def test_live_episode_with_real_probes_and_cognition(fake_run: Path, tmp_path: Path) -> None:
    with local_client(real_app(fake_run, tmp_path)) as c, c.websocket_connect("/ws") as ws:
        ws.receive_text()
        ws.send_text(json.dumps({"type": "start", "task": 0, "init": SUCCESS_INIT}))
        msgs = []
        while not msgs or msgs[-1]["type"] != "episode_end":
            msgs.append(json.loads(ws.receive_text()))
    start = P.EpisodeStart.model_validate(msgs[0])
    steps = [P.Step.model_validate(m) for m in msgs[1:-1]]
    assert [g.index for g in start.subgoals] == [1, 2, 3, 4]
    assert all(len(s.subgoals) == 4 for s in steps)
    believed = set()
    for s in steps:
        assert all("-" not in b.split("(")[0] for b in s.beliefs.asserted)  # DIARC spelling
        assert set(s.beliefs.retracted) <= believed  # only what was believed can be retracted
        believed = (believed - set(s.beliefs.retracted)) | set(s.beliefs.asserted)
    assert steps[0].timings.probes_ms >= 0 and steps[0].timings.model_ms >= 0


def test_replay_of_a_union_store_leaves_undefined_atoms_out(tmp_path: Path) -> None:
    """A stored episode leaves the inconsistent atom undefined (stored false) while the probes read it as true for
    6 steps: its replay asserts no belief from it, counts no violation and scores no disagreement on it."""
    from tests.cognition.test_monitor import FLICKER, STEPS, write_run

    from vlaprobe.configs.monitor import CognitionConfig
    from vlaprobe.live.pipeline import StepBuilder
    from vlaprobe.live.replay import StoreReplays
    from vlaprobe.live.serve import ProbeReading, cognition_factory
    from vlaprobe.live.sources import StoreEpisodes
    from vlaprobe.probes import ProbeSet

    for undefined in None, {1: [FLICKER]}:
        folder = tmp_path / ("union" if undefined else "spatial")
        store, probes = write_run(folder, undefined=undefined, flicker=6, replayable=True)
        readout = ProbeReading(ProbeSet.load(probes))
        builder = partial(StepBuilder, readout=readout, make_cognition=cognition_factory(CognitionConfig()))
        replays = StoreReplays(StoreEpisodes(store), builder)
        record = replays.record("store-t00_i01_a00")
        summary = record.end.summary
        column = record.start.atoms.object.index(FLICKER)
        predicted = [s.predicted.object.values[column] for s in record.steps]
        cells = len(STEPS) * sum(int(readout.probed[h].sum()) for h in ("object", "action"))
        probs = [s.predicted.object.probs[column] for s in record.steps]
        if undefined is None:  # the spatial store: the flicker is believed, violates, disagrees
            assert record.start.defined is None and all(p is not None for p in probs)
            assert sum(predicted) == 6 and summary.violations.get("left_right_converse") == 1
            assert summary.agreement == round(1 - 6 / cells, 4) < 1
        else:  # marked undefined, with no probability a client could read as a prediction
            assert record.start.defined is not None and not record.start.defined.object[column]
            assert sum(record.start.defined.object) == len(record.start.atoms.object) - 1
            assert all(p is None for p in probs)
            assert sum(predicted) == 0 and "left_right_converse" not in summary.violations
            assert not any(FLICKER in s.beliefs.asserted for s in record.steps)
            assert summary.agreement == 1.0
