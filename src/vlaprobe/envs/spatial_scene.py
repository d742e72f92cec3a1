"""The scene all 10 LIBERO-spatial tasks share, as :func:`~vlaprobe.envs.bddl_scene.task_scene` reads it from
their BDDL files, for code that needs the vocabulary without LIBERO (benchmarks, tests, clients).

``tests/envs/test_bddl_scene.py`` pins it equal to every task's BDDL-derived scene, and a LIBERO-marked test
checks it against every task's simulator, so it cannot drift from what collection records.
"""

from __future__ import annotations

from vlaprobe.symbols import Articulation, Goal, Scene

_DRAWERS = tuple(f"wooden_cabinet_1_{p}_region" for p in ("top", "middle", "bottom"))

SPATIAL_SCENE = Scene(
    pickupable=(
        "akita_black_bowl_1",
        "akita_black_bowl_2",
        "cookies_1",
        "glazed_rim_porcelain_ramekin_1",
        "plate_1",
    ),
    fixtures=("wooden_cabinet_1", "flat_stove_1"),
    containers=_DRAWERS,
    container_articulation=(Articulation(threshold=-0.14, below=True),) * 3,
    surfaces=("wooden_cabinet_1_top_side", "flat_stove_1_cook_region"),
    on_off=("flat_stove_1",),
    on_off_articulation=(Articulation(threshold=0.5, below=False),),
    region_parent={
        **dict.fromkeys(_DRAWERS, "wooden_cabinet_1"),
        "wooden_cabinet_1_top_side": "wooden_cabinet_1",
        "flat_stove_1_cook_region": "flat_stove_1",
    },
    close_articulation=(Articulation(threshold=0.0, below=False, strict=True),) * 3,
    off_articulation=(Articulation(threshold=0.0, below=True, strict=True),),
)
"""Tabletop objects, drawers, stove and their articulation thresholds (224 object + 12 action atoms)."""

SPATIAL_GOAL = Goal(pick="akita_black_bowl_1", place="plate_1")
"""Every LIBERO-spatial task's goal: the black bowl on the plate."""
