"""``vlaprobe run``: the experiment end to end, collect → train → cognition → report → results, into one
run folder."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

from vlaprobe.configs import config_to_dict
from vlaprobe.configs.checks import REPORT_FOLDER, RUN_FOLDER, check_run
from vlaprobe.configs.report import ReportConfig
from vlaprobe.configs.run import RunConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import OWNER_FILE, check_owned_folder, mark_folder, write_atomic
from vlaprobe.locks import lock_folder
from vlaprobe.probes.outfolder import check_probe_folder


def check_run_suite(cfg: RunConfig) -> None:
    """What ``check_run`` cannot see from the config alone: the collection's suite checks, and enough
    episodes for the split's folds."""
    from vlaprobe.collection.collect import check_collect_suite
    from vlaprobe.envs.libero import suite_tasks

    c = cfg.collect
    check_collect_suite(c, "collect.")
    episodes = len(c.tasks or suite_tasks(c.env.suite)) * c.episodes_per_task
    if cfg.train.split.folds > episodes and not c.keep_failed:
        raise VlaprobeError(
            f"--train.split.folds {cfg.train.split.folds} needs at least that many episodes; this run keeps "
            f"{episodes}: lower --train.split.folds or collect more"
        )


def stage_configs(cfg: RunConfig) -> RunConfig:
    """The run's config with every stage's paths pointed into ``cfg.out``."""
    out = Path(cfg.out)
    store, probes, report = out / "activations", out / "probes", out / "report"
    control = control_store(cfg) if cfg.control_model else None
    return dataclasses.replace(
        cfg,
        collect=dataclasses.replace(cfg.collect, out=store),
        train=dataclasses.replace(cfg.train, store=store, out=probes, observer_store=control),
        monitor=dataclasses.replace(cfg.monitor, store=store, probes=probes, out=None, json=False),
        report=dataclasses.replace(cfg.report, probes=probes, out=report),
    )


def control_store(cfg: RunConfig) -> Path:
    """Where the control observer's copy of the run's episodes goes."""
    return Path(cfg.out) / "control" / "activations"


def _observe_control(cfg: RunConfig) -> None:
    """The control observer's hidden states on the collected episodes (resumes like collection)."""
    from vlaprobe.collection.reobserve import reobserve

    policy = dataclasses.replace(cfg.collect.policy, model=cfg.control_model)
    added = reobserve(cfg.collect.out, control_store(cfg), policy)
    print(f"      control observer {cfg.control_model}: {len(added)} episodes re-observed", flush=True)


def _save_config(cfg: RunConfig) -> Path:
    path = Path(cfg.out) / "config.json"
    write_atomic(path, json.dumps(config_to_dict(cfg), indent=2) + "\n")
    return path


def run(cfg: RunConfig) -> Path:
    """Run all stages; return the report page. Re-running the same config resumes the collection. A run
    refused before it wrote anything leaves no run folder behind."""
    check_run(cfg)
    check_run_suite(cfg)
    check_owned_folder(cfg.out, RUN_FOLDER)
    out = Path(cfg.out)
    with lock_folder(out):
        existed = out.is_dir()
        fresh = not existed or not any(out.iterdir())
        try:
            return _run(stage_configs(cfg))
        except BaseException:
            if fresh and out.is_dir() and {p.name for p in out.iterdir()} <= {OWNER_FILE}:
                (out / OWNER_FILE).unlink(missing_ok=True)  # nothing of value was written: leave no trace
                if not existed:
                    out.rmdir()
            raise


def _run(cfg: RunConfig) -> Path:
    """The stages, under the run folder's lock."""
    from vlaprobe.cognition.monitor import monitor
    from vlaprobe.collection.collect import collect
    from vlaprobe.probes.results import read_evaluation
    from vlaprobe.probes.train import train_probes
    from vlaprobe.results import build_results, write_results

    assert cfg.train.out is not None and cfg.report.out is not None  # stage_configs set them
    check_probe_folder(cfg.train.out, "--out")
    check_owned_folder(cfg.report.out, REPORT_FOLDER, "--out")
    mark_folder(cfg.out, RUN_FOLDER.owner)
    print(f"[1/4] collect → {cfg.collect.out}", flush=True)
    t0 = time.perf_counter()
    collect(cfg.collect)
    if cfg.control_model:
        _observe_control(cfg)
    t1 = time.perf_counter()
    print(f"[2/4] train → {cfg.train.out}", flush=True)
    train_probes(cfg.train)
    print(f"[3/4] cognition → {cfg.train.out}/monitor.json", flush=True)
    # The cognition over the held-out episodes, on the truth and on the probes; the report adds its section.
    cognition = monitor(cfg.monitor)
    for line in cognition.gaps():
        print(f"      {line}", flush=True)
    t2 = time.perf_counter()
    print(f"[4/4] report → {cfg.report.out}", flush=True)
    page = report(cfg.report)
    # The headline figures, the one file the README and docs quote (scripts/publish_results.py).
    results = write_results(cfg.out, build_results(read_evaluation(Path(cfg.out) / "probes"), cognition))
    print(f"      headline figures → {results}", flush=True)
    t3 = time.perf_counter()
    # Written once every stage has succeeded: a rejected or failed run leaves the last good config in place.
    config_path = _save_config(cfg)
    print(
        f"times: collect {t1 - t0:.0f} s, train + cognition {t2 - t1:.0f} s, report {t3 - t2:.0f} s; config: {config_path}"
    )
    return page


def report(cfg: ReportConfig) -> Path:
    """``vlaprobe report``: the report page with the offline cognition evaluation's and the failure prediction's
    sections when the probe folder has their files."""
    from vlaprobe.cognition.failures_report import report_section as failures_section
    from vlaprobe.cognition.monitor import report_section
    from vlaprobe.reports.report import write_report

    found = [report_section(Path(cfg.probes)), failures_section(Path(cfg.probes))]
    return write_report(cfg, sections=[s for s in found if s is not None])


def refuse_run_report(cfg: ReportConfig) -> None:
    """Refuse to write over the report of a ``vlaprobe run`` folder (one with ``results.json``): the run's
    figures and its report belong together; another report goes elsewhere (``--out``)."""
    from vlaprobe.results import RESULTS_FILE

    run_folder = Path(cfg.probes).parent
    out = Path(cfg.out) if cfg.out is not None else run_folder / "report"
    own = run_folder / "report"
    if (run_folder / RESULTS_FILE).is_file() and out.resolve() == own.resolve():
        raise VlaprobeError(
            f"{own} is the report `vlaprobe run` wrote for {run_folder}; pass --out to write this report "
            f"elsewhere (e.g. --out {run_folder / 'report-2'})"
        )


def report_main(cfg: ReportConfig) -> int:
    """CLI entry of ``vlaprobe report``: write the report and print where it is (never over a run's own)."""
    refuse_run_report(cfg)
    print(f"report written to {report(cfg)}")
    return 0


def main(cfg: RunConfig) -> int:
    """CLI entry: run everything and print where the report is."""
    from vlaprobe.probes.results import read_evaluation

    page = run(cfg)
    for head, h in read_evaluation(Path(cfg.out) / "probes").heads.items():
        value = "undefined" if h.best.value is None else f"{h.best.value:.3f}"
        print(f"{head} atoms: best layer {h.best.layer} ({h.best.metric} {value})")
    print(f"report: {page}")
    return 0
