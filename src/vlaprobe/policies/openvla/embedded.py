"""Models that ship inside the package and load by name, with no download.

``tiny-libero`` is the default observer: the tiny OpenVLA (64 patches of the 224 px image, see
:func:`~vlaprobe.policies.openvla.tiny.tiny_config`) trained by ``vlaprobe finetune`` on the scripted expert's
demonstrations of the 10 LIBERO-spatial tasks (recipe: ``recipes/tiny-libero.yaml``; figures: README). Its
folder is an ordinary checkpoint folder (config.json with ``norm_stats``, ``model.safetensors`` stored in
float16 to stay small, loaded in the run's dtype). ``tiny`` (built from a seed, random weights) is the control.
"""

from __future__ import annotations

from pathlib import Path

WEIGHTS = Path(__file__).parent / "weights"
"""Package folder of the shipped checkpoint folders, one per name."""

EMBEDDED_MODELS: dict[str, str] = {
    "tiny-libero": "the tiny OpenVLA trained on expert demonstrations of LIBERO-spatial (the default observer)",
}
"""Name -> what it is."""

DEFAULT_MODEL = "tiny-libero"
"""The observer of ``vlaprobe run``, ``collect`` and ``serve`` when none is named."""

CONTROL_MODEL = "tiny"
"""The random control observer (seeded weights, same code): what ``vlaprobe run`` compares the default with."""

MODEL_NAMES = ("tiny", *EMBEDDED_MODELS)
"""Every model that loads by name."""


def embedded_folder(name: str) -> Path | None:
    """The shipped checkpoint folder of ``name``, or None when ``name`` is not a shipped model."""
    return WEIGHTS / name if name in EMBEDDED_MODELS else None
