"""Config of ``vlaprobe finetune``: behaviour cloning with OpenVLA's fine-tuning objective."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass
class FinetuneConfig:
    """Train an OpenVLA model (the tiny one or a checkpoint folder) on the expert episodes of collection stores.

    The objective is OpenVLA's: next-token cross-entropy on the 7 action tokens and the stop token, given the
    image and the prompt (teacher forcing); actions are binned with the training data's q01/q99, which are
    written into the checkpoint as ``norm_stats``. Rerunning the same command in the same ``--out`` resumes.
    """

    stores: tuple[Path, ...] = ()
    """Collection stores (``vlaprobe collect --out``) whose episodes are the demonstrations: images, executed
    actions, instructions; in a ``--driver dagger`` store, the expert's labels instead of the executed actions."""
    out: Path = Path("runs/finetune")
    """Run folder: ``checkpoint/`` (a model folder ``--model`` and ``--policy.model`` load), ``metrics.jsonl``,
    ``finetune.json``. A folder holding a checkpoint of the same run is resumed."""
    model: str = "tiny"
    """Initial weights: a seeded model's name ("tiny", "tiny-libero-init": built from ``--model-seed``), a
    shipped model's name ("tiny-libero") or an OpenVLA checkpoint folder (official or vlaprobe-written)."""
    model_seed: int = 0
    """Seed of a seeded model's initial weights (ignored for checkpoint folders)."""
    model_id: str = ""
    """Name written into the checkpoint (``vlaprobe model-info`` shows it). Empty: the --out folder's name."""
    dataset_name: str | None = None
    """Key of the action statistics in ``norm_stats`` (what ``--unnorm-key`` selects when the model runs).
    Default: the stores' suite (``libero_goal``), the key a run with ``--suite libero_goal`` looks for."""
    # --- data ---
    tasks: tuple[int, ...] = ()
    """Train only on the episodes of these task indices (e.g. ``--tasks 0`` to check that the model can learn
    one task); empty: every task in the stores."""
    val_fraction: float = 0.1
    """Share of each task's episodes held out for validation (at least one per task with two or more)."""
    success_only: bool = True
    """Train only on episodes whose task was completed (demonstrations of success). Not applied to
    ``--driver dagger`` stores: their labels are the expert's, whether or not the model completed the task."""
    skip_post_success: bool = True
    """Drop the rows recorded after the goal was reached (``post_success_steps``): not part of the demonstration."""
    drop_noops: bool = True
    """Drop idle steps (no translation or rotation and an unchanged gripper), as OpenVLA's ``*_no_noops``
    LIBERO datasets do."""
    # --- optimisation ---
    epochs: int = 1
    """Passes over the training split (ignored when --max-steps is set)."""
    max_steps: int | None = None
    """Optimizer steps in all; overrides --epochs."""
    batch_size: int = 16
    """Samples per optimizer step (OpenVLA: 16)."""
    lr: float = 5e-4
    """Peak AdamW learning rate (OpenVLA's LoRA fine-tunes: 5e-4)."""
    weight_decay: float = 0.01
    """AdamW's decoupled weight decay (torch's default, which OpenVLA keeps)."""
    warmup_steps: int = 50
    """Linear warm-up from 0 to --lr, then a cosine decay to --min-lr-ratio x --lr at the last step."""
    min_lr_ratio: float = 0.0
    """Learning rate at the end of the cosine, as a share of --lr."""
    grad_clip: float = 1.0
    """Gradient-norm clipping threshold; 0 disables it."""
    seed: int = 0
    """Seed of the split, the sample order and the augmentation (everything random in training)."""
    # --- what trains ---
    lora: bool = False
    """Train LoRA adapters (peft) on every linear layer except ``lm_head`` instead of all weights; the
    checkpoint holds the merged weights (and the adapter, for resuming). For large checkpoints on a GPU."""
    lora_rank: int = 32
    """LoRA rank (OpenVLA: 32); the scale alpha is min(rank, 16) as in OpenVLA."""
    lora_dropout: float = 0.0
    """Dropout on the LoRA branch (OpenVLA: 0)."""
    freeze_vision: bool = False
    """Keep both ViT featurisers fixed; their patch features are computed once and cached (no augmentation)."""
    # --- inputs ---
    augment: bool = False
    """OpenVLA's image augmentation: a random square crop of --crop-scale of the area resized back, and colour
    jitter (brightness 0.2, contrast and saturation 0.8-1.2); seeded."""
    crop_scale: float = 0.9
    """Area share of the random crop (OpenVLA: 0.9; the LIBERO evaluation centre-crops the same share)."""
    # --- evaluation and checkpoints ---
    eval_every: int = 0
    """Validate, log and checkpoint every this many steps; 0: once per epoch. The last step always does."""
    val_max_samples: int = 2000
    """Validation rows used (an even spread over the validation episodes); 0: all."""
    max_minutes: float | None = None
    """Stop cleanly at a checkpoint once this much wall time has passed; rerun the command to continue."""
    # --- hardware ---
    device: str = "auto"
    """"auto" (CUDA when available, else CPU), "cpu", "cuda" or "cuda:N"."""
    bf16: bool = True
    """bf16 autocast on CUDA (LoRA loads the frozen base weights in bf16 too); the CPU always runs fp32."""
    threads: int | None = None
    """torch CPU threads (default: torch's choice). Runs compare bit for bit only at the same thread count."""
    compile: bool = False
    """Compile the training step's forward and backward with ``torch.compile`` (inductor; on a CPU it needs a
    C++ compiler): on a CPU the 56 px tiny model's step ran 1.5x faster (batch 16, 2 threads), the 256-patch
    one's 1.0-1.2x (``bench/finetune.py``), after a one-off compile of a few minutes. Sequences are padded to
    the longest prompt so every step has one shape. Figures agree with the eager step to float32 rounding,
    not bit for bit; compiled runs compare bit for bit with each other at the same thread count."""
    progress: bool = True
    """Show a progress bar (stderr)."""
