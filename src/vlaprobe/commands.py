"""The ``vlaprobe`` subcommands: one line each, a config class and the function that runs it.

Both are named as ``"module:attribute"`` and imported only when the command runs (or its help is shown), so
adding a command is one entry here and importing this module stays cheap.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Command:
    """One ``vlaprobe`` subcommand."""

    config: str
    """"module:Class" of the config dataclass (its fields are the command's flags)."""
    target: str
    """"module:function" that takes the config instance and returns the exit status."""
    help: str
    """One line for ``vlaprobe --help``."""

    def config_class(self) -> type:
        cls = _resolve(self.config)
        assert isinstance(cls, type), self.config
        return cls

    def function(self) -> Callable[[object], object]:
        """The command's entry ``(config) -> exit status``."""
        return _resolve(self.target)  # type: ignore[return-value]


def _resolve(spec: str) -> object:
    module, name = spec.split(":")
    return getattr(importlib.import_module(module), name)


COMMANDS: dict[str, Command] = {
    "run": Command("vlaprobe.configs.run:RunConfig", "vlaprobe.pipeline:main", "The whole experiment: collect, train, report (CPU default)."),
    "tasks": Command("vlaprobe.configs.suite:TasksConfig", "vlaprobe.envs.suite:tasks", "List the suite's tasks (index, instruction)."),
    "atoms": Command("vlaprobe.configs.suite:AtomsConfig", "vlaprobe.envs.suite:atoms", "Print the atoms true at a settled init state."),
    "collect": Command("vlaprobe.configs.collect:CollectConfig", "vlaprobe.cognition.alarm:collect", "Run episodes and record every layer's hidden states with the atoms of each step."),
    "info": Command("vlaprobe.configs.collect:InfoConfig", "vlaprobe.collection.info:info", "Summarize an activation store."),
    "train": Command("vlaprobe.configs.train:TrainConfig", "vlaprobe.probes.train:main", "Train and evaluate per-layer linear probes."),
    "hypotheses": Command("vlaprobe.configs.hypotheses:HypothesesConfig", "vlaprobe.probes.hypotheses_run:main", "H1/H2: best, earliest and steepest layer per head; object-action differences with bootstrap intervals."),
    "compare-splits": Command("vlaprobe.configs.hypotheses:CompareSplitsConfig", "vlaprobe.probes.cross_task:main", "Within-task vs leave-one-task-out probes of one store, predicate by predicate."),
    "cross-suite": Command("vlaprobe.configs.cross_suite:CrossSuiteConfig", "vlaprobe.probes.cross_suite:main", "Probes trained on one suite scored on another suite's store over the atoms both share."),
    "reobserve": Command("vlaprobe.configs.stores:ReobserveConfig", "vlaprobe.collection.reobserve:main", "Another model's hidden states on a store's recorded episodes (same images and atoms): observers compared on the same episodes."),
    "compare-stores": Command("vlaprobe.configs.stores:CompareStoresConfig", "vlaprobe.probes.store_compare:main", "Stores side by side: task and task x time baselines, distinct states, atoms varying within episodes."),
    "report": Command("vlaprobe.configs.report:ReportConfig", "vlaprobe.pipeline:report_main", "Write the heatmap, curves and HTML page."),
    "cognition": Command("vlaprobe.configs.monitor:MonitorConfig", "vlaprobe.cognition.monitor:main", "The offline cognition evaluation: beliefs, rules, subgoals on stored episodes, truth vs probe predictions."),
    "failures": Command("vlaprobe.configs.failures:FailuresConfig", "vlaprobe.cognition.failures:main", "Failure prediction on stored episodes: cognition, hidden-state probe, time baselines; conformal alarms."),
    "model-info": Command("vlaprobe.configs.policy:ModelInfoConfig", "vlaprobe.policies.openvla.commands:model_info", "Load a VLA policy and print its description (with --step: one timed step) as JSON."),
    "serve": Command("vlaprobe.configs.serve:ServeConfig", "vlaprobe.live.serve:main", "The live monitor: stream episodes (simulator, model, probes, cognition) over a WebSocket; record and replay."),
    "finetune": Command("vlaprobe.configs.finetune:FinetuneConfig", "vlaprobe.finetune.command:finetune", "Fine-tune an OpenVLA model (tiny or a checkpoint) on collected expert episodes with OpenVLA's objective."),
    "doctor": Command("vlaprobe.configs.doctor:DoctorConfig", "vlaprobe.doctor.command:doctor", "Check and time what `vlaprobe run` needs on this machine (torch, pins, renderer, assets, model, disk); exit 0 when ready."),
    "save-tiny": Command("vlaprobe.configs.policy:SaveTinyConfig", "vlaprobe.policies.openvla.commands:save_tiny", "Write the seeded tiny OpenVLA as a checkpoint folder (config.json + model.safetensors)."),
}  # fmt: skip
"""Every subcommand by name, in ``vlaprobe --help`` order."""

ALIASES: dict[str, str] = {"monitor": "cognition"}
"""Deprecated command names -> the command they run (each prints one deprecation line on stderr)."""
