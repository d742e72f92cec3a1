"""Configs of ``vlaprobe collect`` (record episodes into an activation store) and ``vlaprobe info``."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.configs.takeover import TakeoverConfig

DriverName = Literal["expert", "policy", "dagger"]
"""Who acts in an episode: the scripted expert, the model, or the model labelled by the expert (DAgger)."""


@dataclass
class CollectConfig:
    """Run LIBERO episodes and record every layer's hidden states with the ground-truth atoms of each step."""

    out: Path = Path("runs/default/activations")
    """Activation store folder. Created if missing; an existing store made with the same settings is resumed."""
    driver: DriverName = "expert"
    """Who acts: the privileged scripted expert (the model only observes, its predicted action is recorded next
    to the executed one), the model itself (the paper's setting), or "dagger": the model acts and the scripted
    expert labels every row with its own action (``expert_action``, what `vlaprobe finetune` then learns from;
    see --dagger-beta and docs/finetune.md)."""
    dagger_beta: float = 0.0
    """Under --driver dagger: the probability that a step executes the expert's action instead of the model's
    (DAgger's beta; 0: the model always acts, the expert only labels)."""
    policy: Annotated[PolicyConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=PolicyConfig)
    """The model whose hidden states are recorded (--model tiny|FOLDER, --pooling, --device, ...). Its --seed
    also seeds every episode (with the task, init state and attempt)."""
    tasks: tuple[int, ...] = ()
    """Task indices to collect (e.g. --tasks 0 1 2). Default: every task of the suite."""
    episodes_per_task: int = 5
    """Successful episodes to keep per task (the paper kept 5)."""
    max_tries_per_task: int | None = None
    """Try budget: init states 0..K-1 (from --first-init on) are tried in order until enough succeed. Default:
    all init states (50) from --first-init. A task that runs out is reported, not an error."""
    first_init: int = 0
    """First init state tried; the ones before it are never run (e.g. --first-init 10 collects demonstrations
    that leave init states 0-9 of every task held out for a closed-loop evaluation)."""
    post_success_steps: int = 10
    """Rows recorded after the first observation where the task succeeds (the expert releases the object and
    lifts the arm; the model keeps observing). 0 ends an episode on its success observation, so the goal
    atom holds in one row per episode and the 1% label filter drops it; with the default the goal atom
    ``on(akita_black_bowl_1,plate_1)`` is true in ~8% of the default run's training steps (docs/collection.md).
    Each episode records its ``success_step`` so analyses can select or exclude the rows after it."""
    perturb: str = ""
    """Perturbations per episode, each with a probability: "drop=0.5,displace=0.3,knock_off=0.3". drop: the
    gripper is forced open while the expert carries the object; displace: the object is moved to a free spot
    before it is grasped; knock_off: it is moved off its target after placement. Drawn from the episode's seed;
    the expert recovers (re-grasps); perturbed rows and episodes are marked in the store (docs/collection.md).
    Default: none."""
    expert_faults: str = ""
    """Faults injected into the scripted expert (--driver expert), natural failures from one driver:
    "noise=0.3,release=0.2,wrong_target=0.2,no_recovery=0.5". noise: Gaussian noise of that standard deviation
    on the expert's motion actions; release: the gripper opens while carrying and the expert gives up;
    wrong_target: the object is placed on another object; no_recovery: the expert gives up instead of
    re-grasping. Probabilities per episode, drawn from its seed; marked per episode with the row from which the
    failure was certain (docs/failures.md). Add --keep-failed to store the failures. Default: none."""
    intervention: Annotated[TakeoverConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=TakeoverConfig)
    """When the scripted expert takes over from the policy (--takeover alarm|random, docs/failures.md)."""
    keep_failed: bool = False
    """Also store failed episodes (marked success=false) instead of only recording that they were tried."""
    workers: int = 1
    """Episodes run in parallel: 1 runs in this process; N > 1 starts N worker processes (or N Ray actors with
    --ray), each with its own simulator and model."""
    ray: str | None = None
    """Run the workers as Ray actors on this cluster: an address ("auto", "ray://host:10001") or "local" to
    start a Ray instance on this machine. Needs the `ray` extra (pip install 'vlaprobe[ray]')."""
    ray_gpus_per_worker: float = 0.0
    """GPUs each Ray actor reserves (e.g. 1 for OpenVLA-7B on a GPU cluster)."""
    threads: int | None = None
    """Torch CPU threads per worker. Default: half the cores divided by --workers (the simulator and the
    software renderer need the rest; oversubscribed OpenMP threads slow the model down ~8x)."""
    progress: bool = True
    """Show a progress bar on stderr."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """Simulator settings (rendering is required: the model needs the image)."""


@dataclass
class InfoConfig:
    """Summarize an activation store."""

    path: tyro.conf.Positional[Path] = Path("runs/default/activations")
    """The store folder (the --out of `vlaprobe collect`)."""
    json: bool = False
    """Print JSON: {"episodes": [{"key", "task", "init", "attempt", "success", "length"}, ...], "layers",
    "hidden_size", "pooling", ...}."""
    verify: bool = False
    """Also read every array of every episode (finds truncated or corrupted chunk files; slower). Without it
    the metadata, shapes and chunk files of every episode are still checked."""
