"""Checkpoints by hub id, offline: a Hugging Face cache folder holding a tiny checkpoint in the hub's layout."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from vlaprobe.errors import VlaprobeError
from vlaprobe.policies.openvla import hub
from vlaprobe.policies.openvla.tiny import LIBERO_SPATIAL_LIKE_STATS

REPO = "someone/openvla-tiny-finetuned-libero-goal"
COMMIT = "0123456789abcdef0123456789abcdef01234567"


def write_hub_cache(hf_home: Path, repo_id: str, source: Path) -> Path:
    """Put the files of ``source`` into ``hf_home``'s hub cache as huggingface_hub lays a download out: blobs named
    by their hash, the revision's snapshot folder of links to them, ``refs/main`` naming the revision."""
    from huggingface_hub.file_download import repo_folder_name

    repo = hf_home / "hub" / repo_folder_name(repo_id=repo_id, repo_type="model")
    snapshot = repo / "snapshots" / COMMIT
    (repo / "blobs").mkdir(parents=True)
    snapshot.mkdir(parents=True)
    for file in sorted(source.iterdir()):
        blob = repo / "blobs" / hashlib.sha256(file.read_bytes()).hexdigest()
        blob.write_bytes(file.read_bytes())
        (snapshot / file.name).symlink_to(os.path.relpath(blob, snapshot))
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text(COMMIT)
    return snapshot


@pytest.fixture(scope="module")
def hf_home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A cache with a tiny checkpoint whose statistics cover spatial and, as OpenVLA's fine-tunes name it, goal."""
    from vlaprobe.policies.openvla import checkpoint
    from vlaprobe.policies.openvla.policy import OpenVLAPolicy

    source = tmp_path_factory.mktemp("checkpoint")
    tiny = OpenVLAPolicy.tiny(seed=3, device="cpu")
    stats = {**LIBERO_SPATIAL_LIKE_STATS, "libero_goal_no_noops": LIBERO_SPATIAL_LIKE_STATS["libero_spatial"]}
    checkpoint.save_checkpoint(source, tiny.model, stats, {"tokenizer": tiny.tokenizer.name, "seed": 3})
    home = tmp_path_factory.mktemp("hf_home")
    write_hub_cache(home, REPO, source)
    return home


def _cli(hf_home: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """``vlaprobe`` in a fresh process (huggingface_hub reads HF_HOME and HF_HUB_OFFLINE when imported)."""
    env = {**os.environ, "HF_HOME": str(hf_home), "HF_HUB_OFFLINE": "1"}
    env.pop("HF_HUB_CACHE", None)
    return subprocess.run(
        [sys.executable, "-m", "vlaprobe.cli", *args], env=env, capture_output=True, text=True, timeout=300
    )


def test_a_hub_id_loads_from_the_cache_offline_with_the_suites_statistics(hf_home: Path) -> None:
    out = _cli(
        hf_home, "model-info", "--policy.model", REPO, "--policy.device", "cpu", "--suite", "libero_goal"
    )
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    assert info["model_id"] == REPO and info["unnorm_key"] == "libero_goal_no_noops"
    assert COMMIT in info["source"] and str(hf_home) in info["source"]


@pytest.fixture
def offline_cache(hf_home: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """This process's huggingface_hub pointed at ``hf_home``, offline (what HF_HOME and HF_HUB_OFFLINE set)."""
    from huggingface_hub import constants

    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(hf_home / "hub"))
    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", True)
    return hf_home


def test_the_default_suite_reads_its_own_statistics(offline_cache: Path) -> None:
    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.policies import make_policy

    assert make_policy(PolicyConfig(REPO, device="cpu")).describe()["unnorm_key"] == "libero_spatial"


def test_a_missing_download_names_the_command_that_fetches_it(
    offline_cache: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vlaprobe.cli import main

    assert main(["model-info", "--policy.model", "openvla/openvla-7b-finetuned-libero-goal"]) == 2
    line = capsys.readouterr().err.strip()
    assert len(line.splitlines()) == 1 and "not in the Hugging Face cache" in line
    assert "hf download openvla/openvla-7b-finetuned-libero-goal --include 'config.json'" in line
    empty = offline_cache / "hub" / "models--someone--empty" / "snapshots" / COMMIT
    empty.mkdir(parents=True)
    (empty.parents[1] / "refs").mkdir()
    (empty.parents[1] / "refs" / "main").write_text(COMMIT)
    (empty / "config.json").write_text("{}")
    with pytest.raises(
        VlaprobeError, match=r"lacks \*\.safetensors; fetch it with `hf download someone/empty"
    ):
        hub.hub_folder("someone/empty")


def test_a_hub_id_is_owner_slash_name_that_is_not_a_folder(tmp_path: Path, monkeypatch) -> None:
    assert hub.is_hub_id("openvla/openvla-7b-finetuned-libero-10")
    assert (
        not hub.is_hub_id("tiny-libero") and not hub.is_hub_id("/ckpt/openvla") and not hub.is_hub_id("a/b/c")
    )
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs" / "ckpt").mkdir(parents=True)
    assert not hub.is_hub_id("runs/ckpt")  # an existing folder of that shape is a folder


def test_only_the_loaders_files_are_fetched() -> None:
    import fnmatch

    official = [
        "config.json",
        "dataset_statistics.json",
        "tokenizer.json",
        "model-00001-of-00003.safetensors",
        "model.safetensors.index.json",
        "modeling_prismatic.py",
        "tokenizer.model",
        "preprocessor_config.json",
        "README.md",
    ]
    fetched = [f for f in official if any(fnmatch.fnmatch(f, p) for p in hub.LOADER_FILES)]
    assert fetched == official[:5]
