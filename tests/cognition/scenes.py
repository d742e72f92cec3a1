"""Hand-made beliefs over LIBERO-spatial's real vocabulary (224 object + 12 action atoms), no simulator."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from vlaprobe.envs.spatial_scene import SPATIAL_GOAL, SPATIAL_SCENE
from vlaprobe.symbols import build_vocabulary

SCENE = SPATIAL_SCENE
DRAWERS = SCENE.containers
VOCAB = build_vocabulary(SCENE)
GOAL = SPATIAL_GOAL
BOWL, PLATE = GOAL.pick, GOAL.place
BOWL2, COOKIES, RAMEKIN = "akita_black_bowl_2", "cookies_1", "glazed_rim_porcelain_ramekin_1"
TOP = DRAWERS[0]
APPROACH = frozenset({f"should-move-towards({BOWL})"})
"""A consistent state: nothing but the directive to move towards the bowl (the goal does not hold)."""
CARRY = frozenset({f"grasped({BOWL})", f"should-move-towards({PLATE})"})
PLACED = frozenset({f"on({BOWL},{PLATE})"})


def arrays(atoms: Iterable[str]) -> tuple[np.ndarray, np.ndarray]:
    """(object values, action values) with exactly ``atoms`` true."""
    atoms = set(atoms)
    unknown = atoms - set(VOCAB.object_atoms) - set(VOCAB.action_atoms)
    assert not unknown, unknown
    obj = np.array([a in atoms for a in VOCAB.object_atoms])
    act = np.array([a in atoms for a in VOCAB.action_atoms])
    return obj, act
