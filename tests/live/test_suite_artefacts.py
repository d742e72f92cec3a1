"""The suite is written into stores, probes and the live messages; artefacts of two suites are not combined."""

from __future__ import annotations

from pathlib import Path

import pytest
from tests.collection.fakes import make_fake_worker
from tests.collection.test_collect import config

from vlaprobe.cli import main
from vlaprobe.collection.store import read_store_meta
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.finetune import FinetuneConfig
from vlaprobe.configs.monitor import MonitorConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.probemeta import read_probes_meta
from vlaprobe.probes.probeset import ProbeSet


@pytest.fixture(scope="module")
def goal_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small store of fake episodes collected with ``--suite libero_goal`` (the real writer)."""
    from vlaprobe.collection.collect import collect

    out = tmp_path_factory.mktemp("goal") / "activations"
    collect(config(out, env=EnvConfig(suite="libero_goal", max_steps=6, image_size=16)), make_fake_worker)
    return out


def test_stores_and_probes_record_their_suite(fake_run: Path, goal_store: Path) -> None:
    assert read_store_meta(goal_store).suite == "libero_goal"
    assert read_store_meta(fake_run / "activations").suite == "libero_spatial"
    assert read_probes_meta(fake_run / "probes").suite == "libero_spatial"
    assert ProbeSet.load(fake_run / "probes", suite="libero_spatial").suite == "libero_spatial"
    with pytest.raises(VlaprobeError, match="trained on libero_spatial episodes, not libero_goal"):
        ProbeSet.load(fake_run / "probes", suite="libero_goal")


def test_probes_trained_on_a_suite_say_so_in_every_file(goal_store: Path, tmp_path: Path) -> None:
    from vlaprobe.configs.train import TrainConfig
    from vlaprobe.probes.results import read_evaluation
    from vlaprobe.probes.train import train_probes
    from vlaprobe.results import build_results

    out = tmp_path / "probes"
    train_probes(
        TrainConfig(store=goal_store, out=out, bootstrap=5, auprc_bootstrap=2, shuffled_control=False)
    )
    assert read_probes_meta(out).suite == "libero_goal"
    evaluation = read_evaluation(out)
    assert evaluation.suite == "libero_goal" and build_results(evaluation, None).suite == "libero_goal"


def test_the_cognition_refuses_a_store_of_another_suite(
    fake_run: Path, goal_store: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vlaprobe.cognition.monitor import monitor

    with pytest.raises(VlaprobeError, match=r"is from libero_goal, the probes in .* from libero_spatial"):
        monitor(MonitorConfig(probes=fake_run / "probes", store=goal_store, out=tmp_path / "m"))
    code = main(["cognition", "--probes", str(fake_run / "probes"), "--store", str(goal_store)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "libero_goal" in err


def test_failure_prediction_refuses_probes_of_another_suite(
    fake_run: Path, goal_store: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vlaprobe.cognition.failures_load import load_episodes
    from vlaprobe.configs.failures import FailuresConfig

    cfg = FailuresConfig(store=goal_store, probes=fake_run / "probes", out=tmp_path / "f")
    with pytest.raises(VlaprobeError, match=r"is from libero_goal, the probes in .* from libero_spatial"):
        load_episodes(cfg)
    code = main(
        ["failures", "--store", str(goal_store), "--probes", str(fake_run / "probes"), "--out", str(cfg.out)]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "libero_goal" in err


def test_train_refuses_an_observer_store_of_another_suite(
    fake_run: Path, goal_store: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The observer control probes the same atoms on a second observer: a store of another suite is refused
    before any work, even where another model observed it."""
    import json
    import shutil

    from vlaprobe.configs.train import TrainConfig
    from vlaprobe.probes.train import train_probes

    other = tmp_path / "observer"
    shutil.copytree(goal_store, other)
    root = json.loads((other / "zarr.json").read_text())
    root["attributes"]["model_id"] = "another-observer"
    (other / "zarr.json").write_text(json.dumps(root))
    cfg = TrainConfig(store=fake_run / "activations", observer_store=other, out=tmp_path / "p")
    with pytest.raises(
        VlaprobeError, match=r"--store .* is from libero_spatial, --observer-store .* from libero_goal"
    ):
        train_probes(cfg)
    argv = ["train", "--store", str(cfg.store), "--observer-store", str(other), "--out", str(cfg.out)]
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "libero_goal" in err and not cfg.out.exists()


def test_hypotheses_refuse_a_store_of_another_suite(
    fake_run: Path, goal_store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["hypotheses", "--probes", str(fake_run / "probes"), "--store", str(goal_store)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "is from libero_goal, the probes in" in err and "from libero_spatial" in err


def test_the_live_server_refuses_a_store_of_another_suite(fake_run: Path, goal_store: Path) -> None:
    from vlaprobe.live.serve import store_replays

    probes = ProbeSet.load(fake_run / "probes")
    with pytest.raises(VlaprobeError, match=r"--store .* is from libero_goal"):
        store_replays(goal_store, probes, make_builder=None)  # type: ignore[arg-type]


def test_finetune_refuses_stores_of_two_suites(fake_run: Path, goal_store: Path, tmp_path: Path) -> None:
    from vlaprobe.finetune.command import build_trainer

    cfg = FinetuneConfig(stores=(fake_run / "activations", goal_store), out=tmp_path / "ft", model="tiny")
    with pytest.raises(VlaprobeError, match=r"is from libero_spatial, store .* from libero_goal"):
        build_trainer(cfg)
