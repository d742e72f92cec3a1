"""Simulator configuration."""

from __future__ import annotations

import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro

Inits = Literal["fixed", "sampled", "sampled-swap"]

SuiteName = Literal["libero_spatial", "libero_object", "libero_goal", "libero_10", "libero_90"]
"""The LIBERO benchmark suites, named as LIBERO's ``benchmark`` names them (defined once, imported elsewhere)."""
SUITES: tuple[SuiteName, ...] = typing.get_args(SuiteName)


def same_suite(first: str, first_suite: str, second: str, second_suite: str) -> None:
    """Refuse (one line) to combine two artefacts of different suites: their atoms, tasks and goals differ."""
    if first_suite != second_suite:
        from vlaprobe.errors import VlaprobeError

        raise VlaprobeError(
            f"{first} is from {first_suite}, {second} from {second_suite}; combine artefacts of one suite "
            f"(collect, train and serve with the same --suite; probes of one suite on another's store: "
            f"vlaprobe cross-suite)"
        )


@dataclass
class EnvConfig:
    """How to build a LIBERO task environment."""

    suite: Annotated[SuiteName, tyro.conf.arg(aliases=("--suite",))] = "libero_spatial"
    """LIBERO benchmark suite (``--env.suite`` or ``--suite``). The scene, vocabulary and goal of every suite are
    read from its BDDL files (docs/symbols.md); every command takes every suite, and the scripted expert refuses
    (one line, before any work) a task whose goal no skill of it handles."""
    assets: Path | None = None
    """LIBERO assets folder (meshes, textures, scenes). Default: $VLAPROBE_LIBERO_ASSETS, else the
    assets inside the installed libero package, else LIBERO's own download."""
    image_size: int = 256
    """Side of the square agentview render in pixels (OpenVLA's LIBERO evaluation renders 256)."""
    settle_steps: int = 10
    """No-op steps (gripper open) after each reset so objects fall onto their supports: LIBERO's init
    states place them ~7 cm above; OpenVLA's evaluation waits 10 steps too."""
    render: bool = True
    """Render the agentview camera. Without it steps are ~8x faster but there is no image."""
    inits: Annotated[Inits, tyro.conf.arg(prefix_name=False)] = "fixed"
    """Where objects start (``--inits``, the same flag in collect, run and serve): "fixed" resets to the task's
    50 saved init states (the paper); "sampled" draws a new layout from the task's BDDL regions with LIBERO's
    own placement sampler, one reproducible layout per sample index (its seed is stored with the episode), and
    re-draws layouts that fall, tip, intersect or leave their region (docs/collection.md); "sampled-swap" also
    permutes which table region each movable object starts in (one permutation per draw), re-drawing layouts
    where the instruction no longer names the object to pick alone (docs/collection.md)."""
    max_steps: int = 300
    """Step budget of one episode (OpenVLA's LIBERO-spatial evaluation allows 220 after settling)."""
    layout_seed: tyro.conf.Suppress[int] = 0
    """Seed of the sampled layouts (``--inits sampled|sampled-swap``): a layout is a function of the suite, the
    task, this seed and the sample index. Not a flag: `vlaprobe collect` and `serve` set it from their ``--seed``."""
