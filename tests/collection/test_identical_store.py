"""A store collected after the step loop moved to ``vlaprobe.rollout`` equals one collected before (#9).

The fingerprints in ``data/`` were taken from stores collected by the code before the refactor (per-array
SHA-256 of the bytes; ``tests/collection/fingerprint.py``). The atom arrays are not compared byte for byte:
the ``grasped`` / ``should-move-towards`` definitions (and with them the detectors' inputs) change in #10
independently of the loop. They are instead checked to be the current detectors applied to the stored world
states, which are compared exactly, as is everything else the loop records.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from tests.collection.fakes import make_fake_worker
from tests.collection.fingerprint import compare, store_fingerprint
from tests.collection.test_collect import config

import vlaprobe
from vlaprobe.collection.collect import collect
from vlaprobe.collection.episode import stored_scene, world_states
from vlaprobe.collection.store import ActivationStore
from vlaprobe.symbols import Labeler

DATA = Path(__file__).parent / "data"
ATOMS = ("object_atoms", "action_atoms")


def _labels_follow_world_states(path: Path) -> None:
    for _, ep in ActivationStore.open(path).iter_episodes():
        labeler = Labeler(*stored_scene(ep.attrs))
        bits = [labeler(s) for s in world_states(ep)]
        np.testing.assert_array_equal(ep["object_atoms"], np.stack([b[0] for b in bits]))
        np.testing.assert_array_equal(ep["action_atoms"], np.stack([b[1] for b in bits]))


def test_fake_store_is_identical_to_the_one_before_the_refactor(tmp_path: Path) -> None:
    out = tmp_path / "store"
    collect(config(out, keep_failed=True, post_success_steps=0), make_fake_worker)
    expected = json.loads((DATA / "fingerprint_fakes.json").read_text())
    assert compare(expected, store_fingerprint(out), skip=ATOMS) == []
    _labels_follow_world_states(out)


def test_the_comparison_can_fail(tmp_path: Path) -> None:
    out = tmp_path / "store"
    collect(config(out, keep_failed=True, post_success_steps=1), make_fake_worker)
    expected = json.loads((DATA / "fingerprint_fakes.json").read_text())
    problems = compare(expected, store_fingerprint(out), skip=ATOMS)
    assert any("/hidden" in p for p in problems) and any("info" in p for p in problems)


# The fingerprint's simulator floats depend on the BLAS kernel numpy's OpenBLAS picks at run time for the CPU
# (DYNAMIC_ARCH): robosuite's operational-space controller (mass-matrix inverse, Jacobian products) and the
# expert's geometry go through it, and with AVX-512 kernels (e.g. on an AVX-512 EPYC) the results differ in their
# last bits, which MuJoCo carries into every later state (same 95 steps, stored actions, images and action
# tokens; sums equal to ~3e-15). Measured: OPENBLAS_CORETYPE=Haswell alone restores every byte, disabling numpy's
# own AVX-512 loops alone does not, and the commit that took the fingerprint gives the same new bytes on an
# AVX-512 machine as today's code. The fingerprint was taken where OpenBLAS ran its Haswell (AVX2) kernels; the
# collection runs in a child process pinned to them (the variable must be set before numpy loads), so the
# comparison stays byte for byte on any x86-64 CPU with AVX2.
PINNED_BLAS = {"OPENBLAS_CORETYPE": "Haswell"}
_COLLECT = """
import sys
from pathlib import Path
from vlaprobe.collection.collect import collect
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
# The fingerprint's settings: task 0, one successful episode, the tiny model on 1 CPU thread.
collect(CollectConfig(
    out=Path(sys.argv[1]), tasks=(0,), episodes_per_task=1, policy=PolicyConfig(model="tiny", device="cpu"),
    progress=False, threads=1, post_success_steps=0, env=EnvConfig(image_size=128),
))
"""


@pytest.mark.libero
def test_libero_store_is_identical_to_the_one_before_the_refactor(tmp_path: Path) -> None:
    out = tmp_path / "store"
    src = str(Path(vlaprobe.__file__).parents[1])  # the child imports the vlaprobe under test
    env = {
        **os.environ,
        **PINNED_BLAS,
        "PYTHONPATH": os.pathsep.join([src, os.environ.get("PYTHONPATH", "")]),
    }
    subprocess.run([sys.executable, "-c", _COLLECT, str(out)], env=env, check=True, timeout=1800)
    expected = json.loads((DATA / "fingerprint_libero.json").read_text())
    # The model's float outputs are compared by their sums (torch's kernels may round differently on
    # another CPU); the simulator's arrays, the images and the action tokens byte for byte.
    tolerance = {"hidden": 1e-4, "predicted_action": 1e-4}
    assert compare(expected, store_fingerprint(out), skip=ATOMS, float_tolerance=tolerance) == []
    _labels_follow_world_states(out)
