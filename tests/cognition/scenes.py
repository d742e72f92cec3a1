"""Hand-made beliefs over LIBERO-spatial's real vocabulary (224 object + 12 action atoms), no simulator."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from vlaprobe.symbols import Articulation, Goal, Scene, build_vocabulary

DRAWERS = tuple(f"wooden_cabinet_1_{p}_region" for p in ("top", "middle", "bottom"))
SCENE = Scene(
    pickupable=(
        "akita_black_bowl_1",
        "akita_black_bowl_2",
        "cookies_1",
        "glazed_rim_porcelain_ramekin_1",
        "plate_1",
    ),
    fixtures=("wooden_cabinet_1", "flat_stove_1"),
    containers=DRAWERS,
    container_articulation=(Articulation(-0.14, True),) * 3,
    on_off=("flat_stove_1",),
    on_off_articulation=(Articulation(0.5, False),),
)
VOCAB = build_vocabulary(SCENE)
GOAL = Goal("akita_black_bowl_1", "plate_1")
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
