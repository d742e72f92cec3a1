"""Config of ``vlaprobe run``: the whole experiment, collect → train → cognition → report, in one folder."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.monitor import MonitorConfig
from vlaprobe.configs.report import ReportConfig
from vlaprobe.configs.train import TrainConfig


def _default_collect() -> CollectConfig:
    # Two worker processes use both cores of a laptop-class CPU; every task of the suite is collected. Three
    # successful episodes per task keep the CPU default within 20 minutes on 2 cores (the paper kept 5:
    # --collect.episodes-per-task 5). Init states from 40 on: the trained default observer (tiny-libero) was
    # trained on init states 0-2 and 10-16 (docs/tiny-libero.md), so it never saw these scenes.
    return CollectConfig(workers=2, episodes_per_task=3, first_init=40)


def _default_train() -> TrainConfig:
    # The run answers whether any layer adds information beyond task x time, so it fits the conditional
    # probes (one warm-started fit per baseline and fold, no C search of their own: docs/timings.md;
    # `vlaprobe train` alone leaves them off).
    return TrainConfig(conditional=True)


@dataclass
class RunConfig:
    """Collect hidden states and atoms, train the per-layer probes, run the cognition over the held-out
    episodes (the offline cognition evaluation, ``vlaprobe cognition``), and write the report.

    The embedded default runs on a CPU with no downloads: the scripted expert drives LIBERO-spatial and the
    tiny OpenVLA-shaped model observes. ``--model /path/to/openvla-7b`` (with
    ``--collect.driver policy``) runs the paper's setting instead. The stages' own output paths
    (``collect.out``, ``train.store``, ``train.out``, ``monitor.store``, ``monitor.probes``, ``monitor.out``,
    ``report.probes``, ``report.out``) are derived from
    ``--out`` and ignored here. Once every stage has succeeded the full config is saved as ``<out>/config.json``
    (a rejected or failed run leaves the previous one); ``vlaprobe run --config
    <out>/config.json`` repeats the run (it resumes: complete episodes are kept).
    """

    out: Path = Path("runs/default")
    """Run folder: activations/, probes/, report/ and config.json land here."""
    collect: CollectConfig = field(default_factory=_default_collect)
    """Collection settings (driver, model, tasks, episodes per task, workers...)."""
    train: TrainConfig = field(default_factory=_default_train)
    """Probe training and evaluation settings (conditional probing on: ``--train.no-conditional`` skips it)."""
    monitor: MonitorConfig = field(default_factory=MonitorConfig)
    """Cognition settings (extra --monitor.rules files, debounce...) for the offline cognition evaluation over the test episodes."""
    report: ReportConfig = field(default_factory=ReportConfig)
    """Report settings."""
    control_model: str = "tiny-libero-init"
    """The control observer: this model (a name as for --model, or a checkpoint folder) is shown the
    images of the same episodes (``<out>/control/activations``, a batched pass, no second simulation), its
    probes are trained and evaluated with the same split and resamples as the observer's (the observer
    control of ``vlaprobe train``), and the report compares the two layer by layer. Default: the trained
    default's network before training (random seeded weights of the same shape); "tiny" is the random tiny
    model with OpenVLA's 256 patches; "" skips the control."""
