"""`vlaprobe serve --suite libero_goal` on LIBERO with the tiny model: the suite's tasks, atoms and each task's own
goal conjunction (slow: libero mark). Random probes: the plumbing, not what the probes know."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from tests.live.fakes import LiveServer, random_probes
from websockets.sync.client import connect

from vlaprobe.cognition.plan import conjunct_subgoals, task_goal
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.serve import ServeConfig
from vlaprobe.envs.libero import LiberoTaskEnv, suite_tasks
from vlaprobe.live.app import create_app
from vlaprobe.live.serve import build_engine, limits_of, load_probes

pytestmark = [pytest.mark.libero, pytest.mark.timeout(600), pytest.mark.heavy]
SUITE = "libero_goal"
TASK = 7  # turn on the stove: TurnOn(flat_stove_1), no pick-and-place goal
STEPS = 6


@pytest.fixture(scope="module")
def expected(tmp_path_factory: pytest.TempPathFactory) -> dict:
    env = LiberoTaskEnv(TASK, EnvConfig(suite=SUITE))
    vocab, goal = env.labeler.vocabulary, task_goal(env.goal_conjunction, env.scene)
    env.close()
    atoms = {"object": list(vocab.object_atoms), "action": list(vocab.action_atoms)}
    probes = random_probes(
        tmp_path_factory.mktemp("run") / "probes", "tiny-openvla-seed0", 33, 64, atoms, suite=SUITE
    )
    names = [n for c in goal.conjuncts for n in conjunct_subgoals(c, goal).names]
    return {"probes": probes, "atoms": atoms, "subgoals": names, "objects": goal.objects()}


def test_serve_suite_streams_the_tasks_own_goal(expected: dict, tmp_path: Path) -> None:
    cfg = ServeConfig(
        probes=expected["probes"], model="tiny", device="cpu", recordings=tmp_path, env=EnvConfig(suite=SUITE)
    )
    app = create_app(build_engine(cfg, load_probes(cfg)), limits_of(cfg, None))
    with LiveServer(app) as srv, connect(srv.url, max_size=None) as ws:
        hello = json.loads(ws.recv(timeout=30))
        assert hello["suite"] == SUITE
        assert [(t["index"], t["instruction"]) for t in hello["tasks"]] == list(suite_tasks(SUITE))
        ws.send(
            json.dumps({"type": "start", "task": TASK, "init": 0, "driver": "expert", "max_steps": STEPS})
        )
        msgs = []
        while not msgs or msgs[-1]["type"] != "episode_end":
            msgs.append(json.loads(ws.recv(timeout=120)))
    start, steps = msgs[0], [m for m in msgs if m["type"] == "step"]
    assert start["type"] == "episode_start" and start["suite"] == SUITE
    assert start["atoms"] == expected["atoms"]
    assert (
        [g["name"] for g in start["subgoals"]]
        == expected["subgoals"]
        == [
            "should-move-towards(flat_stove_1)",
            "turned-on(flat_stove_1)",
        ]
    )
    assert start["goal_objects"] == expected["objects"] == ["flat_stove_1"]
    assert len(steps) == STEPS and all(
        len(s["truth"]["object"]) == len(expected["atoms"]["object"]) for s in steps
    )
    assert [g["name"] for g in steps[-1]["truth_subgoals"]] == expected["subgoals"]
