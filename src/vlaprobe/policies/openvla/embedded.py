"""Models that ship inside the package and load by name, with no download.

``tiny-libero`` is the default observer: the tiny OpenVLA (64 patches of the 224 px image, see
:func:`~vlaprobe.policies.openvla.tiny.tiny_config`) trained by ``vlaprobe finetune`` on the scripted expert's
demonstrations of the 10 LIBERO-spatial tasks (recipe: ``recipes/tiny-libero.yaml``; figures:
docs/tiny-libero.md). Its folder is an ordinary checkpoint folder (config.json with ``norm_stats``,
``model.safetensors`` stored in float16 to stay small, loaded in the run's dtype). ``tiny-libero-init`` (its
starting weights, built from a seed) is the control observer; ``tiny`` is the random tiny model with OpenVLA's
256 patches.
"""

from __future__ import annotations

from pathlib import Path

WEIGHTS = Path(__file__).parent / "weights"
"""Package folder of the shipped checkpoint folders, one per name."""

EMBEDDED_MODELS: dict[str, str] = {
    "tiny-libero": "the tiny OpenVLA trained on expert demonstrations of LIBERO-spatial (the default observer)",
    "tiny-libero-diverse": "tiny-libero's shape trained on sampled layouts with perturbations and recovery "
    "(recipes/tiny-libero-diverse.yaml; issue 38's observer that must look)",
}
"""Name -> what it is."""

DEFAULT_MODEL = "tiny-libero"
"""The observer of ``vlaprobe run``, ``collect`` and ``serve`` when none is named."""

SEEDED_MODELS: dict[str, int] = {"tiny": 14, "tiny-libero-init": 28}
"""Random tiny models built from ``--seed`` (no file), by name -> ViT patch size. ``tiny`` has OpenVLA's 256
patches; ``tiny-libero-init`` has tiny-libero's shape (64 patches) and, with seed 0, exactly the weights its
training started from (``vlaprobe save-tiny --patch-size 28``)."""

CONTROL_MODEL = "tiny-libero-init"
"""The random control observer of ``vlaprobe run``: the default observer before its training (same network,
same code, seeded weights), so the comparison isolates what training changed."""

MODEL_NAMES = (*SEEDED_MODELS, *EMBEDDED_MODELS)
"""Every model that loads by name."""


def embedded_folder(name: str) -> Path | None:
    """The shipped checkpoint folder of ``name``, or None when ``name`` is not a shipped model."""
    return WEIGHTS / name if name in EMBEDDED_MODELS else None
