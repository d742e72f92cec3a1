"""`vlaprobe serve --suite libero_goal` on LIBERO with the tiny model: the suite's tasks, atoms and each task's own
goal conjunction (slow: libero mark). Random probes: the plumbing, not what the probes know."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
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


UNION_SUITE, UNION_TASK = "libero_object", 0  # the tasks have different objects: the union of their atoms


def test_serve_union_suite_marks_the_atoms_the_task_lacks(tmp_path: Path) -> None:
    """Probes over LIBERO-object's union vocabulary (as probes of a store of all its tasks are): a live episode
    of one task marks the other tasks' atoms undefined, as the collector records them for its episodes."""
    from vlaprobe.envs.suite_vocabulary import suite_vocabulary

    suite = suite_vocabulary(UNION_SUITE)
    atoms = {h: list(suite.vocabulary.atoms(h)) for h in ("object", "action")}
    env = LiberoTaskEnv(UNION_TASK, EnvConfig(suite=UNION_SUITE))
    undefined_action = set(env.labeler.undefined_action_atoms)  # should-move-towards: an In goal
    env.close()
    defined = {
        "object": suite.defined("object")[UNION_TASK].tolist(),
        "action": [
            bool(d) and a not in undefined_action
            for a, d in zip(atoms["action"], suite.defined("action")[UNION_TASK], strict=True)
        ],
    }
    probes = random_probes(tmp_path / "probes", "tiny-openvla-seed0", 33, 64, atoms, suite=UNION_SUITE)
    cfg = ServeConfig(
        probes=probes,
        model="tiny",
        device="cpu",
        recordings=tmp_path / "live",
        env=EnvConfig(suite=UNION_SUITE),
    )
    app = create_app(build_engine(cfg, load_probes(cfg)), limits_of(cfg, None))
    with LiveServer(app) as srv, connect(srv.url, max_size=None) as ws:
        hello = json.loads(ws.recv(timeout=30))
        start = {"type": "start", "task": UNION_TASK, "init": 0, "driver": "expert", "max_steps": STEPS}
        ws.send(json.dumps(start))
        msgs = []
        while not msgs or msgs[-1]["type"] != "episode_end":
            msgs.append(json.loads(ws.recv(timeout=120)))
    assert hello["protocol"] == 5 and hello["probes"]["atoms"] == atoms
    assert [t["index"] for t in hello["tasks"]] == list(range(10))
    first, steps = msgs[0], [m for m in msgs if m["type"] == "step"]
    assert first["atoms"] == atoms and first["defined"] == defined and len(steps) == STEPS
    assert sum(defined["object"]) < len(atoms["object"])  # most of the union's atoms: other tasks' objects
    for h in ("object", "action"):
        undefined = ~np.array(defined[h])
        for s in steps:
            probs = np.array([p is not None for p in s["predicted"][h]["probs"]])
            assert not probs[undefined].any() and probs[~undefined].any()
            assert not np.array(s["predicted"][h]["values"], bool)[undefined].any()
            assert not np.array(s["truth"][h], bool)[undefined].any()
    truth = np.array([s["truth"]["object"] for s in steps], bool)
    assert truth[:, np.array(defined["object"])].any()  # the task's own labels, in their union columns
    from vlaprobe.cognition import diarc_term

    never = {diarc_term(a) for a, d in zip(atoms["object"], defined["object"], strict=True) if not d}
    assert not never & {b for s in steps for b in s["beliefs"]["asserted"]}


NINETY, NINETY_TASK, NO_SKILL_TASK = "libero_90", 20, 33  # turn on the stove; close the microwave (no skill)


def test_serve_libero_90_lists_its_tasks_and_refuses_an_expert_episode_without_a_skill(
    tmp_path: Path,
) -> None:
    from vlaprobe.envs.bddl_scene import task_scene
    from vlaprobe.symbols.vocabulary import build_vocabulary

    vocab = build_vocabulary(task_scene(NINETY, NINETY_TASK))
    atoms = {"object": list(vocab.object_atoms), "action": list(vocab.action_atoms)}
    probes = random_probes(tmp_path / "probes", "tiny-openvla-seed0", 33, 64, atoms, suite=NINETY)
    cfg = ServeConfig(
        probes=probes, model="tiny", device="cpu", recordings=tmp_path / "live", env=EnvConfig(suite=NINETY)
    )
    app = create_app(build_engine(cfg, load_probes(cfg)), limits_of(cfg, None))
    with LiveServer(app) as srv, connect(srv.url, max_size=None) as ws:
        hello = json.loads(ws.recv(timeout=30))
        assert hello["suite"] == NINETY and len(hello["tasks"]) == 90
        start = {"type": "start", "task": NO_SKILL_TASK, "init": 0, "driver": "expert", "max_steps": STEPS}
        ws.send(json.dumps(start))
        error = json.loads(ws.recv(timeout=30))
        assert error["type"] == "error" and "\n" not in error["message"]
        assert (
            "task 33: the scripted expert has no skill for the goal conjunct Close(microwave_1); start it with "
            "driver 'policy'" in error["message"]
        )
        ws.send(json.dumps({**start, "task": NINETY_TASK}))
        msgs = []
        while not msgs or msgs[-1]["type"] != "episode_end":
            msgs.append(json.loads(ws.recv(timeout=120)))
    assert msgs[0]["type"] == "episode_start" and msgs[0]["suite"] == NINETY and msgs[0]["atoms"] == atoms
    assert [g["name"] for g in msgs[0]["subgoals"]] == [
        "should-move-towards(flat_stove_1)",
        "turned-on(flat_stove_1)",
    ]
    assert len([m for m in msgs if m["type"] == "step"]) == STEPS
