"""The machine's checks, each failure simulated: a wrong pin, stale metadata, an old Python, a full disk, a
missing tool, a GPU asked for on a CPU machine."""

from __future__ import annotations

import shutil
from collections import namedtuple
from importlib import metadata
from pathlib import Path

import pytest

from vlaprobe.configs.doctor import DoctorConfig
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.doctor import system
from vlaprobe.doctor.report import timed

REQUIRES = [
    "torch>=2.5",
    "numpy<2.3,>=1.26",
    "mujoco==3.3.0",
    "transformers>=4.48",
    "pytest>=8; extra == 'dev'",
    'libero==0.1.1; extra == "libero"',
    'bddl==1.0.1; extra == "libero"',
    'robosuite==1.4.0; extra == "libero"',
]
"""vlaprobe's ``Requires-Dist`` as installed metadata gives it (the dependencies, the dev and libero extras)."""

INSTALLED = {
    "torch": "2.13.0+cpu",
    "numpy": "2.2.6",
    "mujoco": "3.3.0",
    "transformers": "5.25.0",
    "libero": "0.1.1",
    "bddl": "1.0.1",
    "robosuite": "1.4.0",
}


@pytest.fixture
def packages(monkeypatch: pytest.MonkeyPatch) -> dict[str, str | None]:
    """vlaprobe's metadata and the installed versions, replaced by :data:`REQUIRES` and a copy of :data:`INSTALLED`
    that a test may change."""
    versions: dict[str, str | None] = dict(INSTALLED)
    monkeypatch.setattr(system.metadata, "requires", lambda name: list(REQUIRES))
    monkeypatch.setattr(system, "installed", lambda name: versions.get(name))
    return versions


def by_name(checks: list[system.Check]) -> dict[str, system.Check]:
    return {c.name: c for c in checks}


def test_the_pins_come_from_the_metadata_and_all_pass(packages: dict[str, str | None]) -> None:
    checks = by_name(system.pin_checks())
    assert [c for c in checks.values() if c.status != "ok"] == []
    assert checks["version.mujoco"].summary == "3.3.0 (pin ==3.3.0)"
    assert checks["version.libero"].figures == {"installed": "0.1.1", "pin": "libero==0.1.1"}
    assert (
        checks["requirements"].summary == "the 1 other requirements are met"
    )  # numpy; torch has its own check


def test_a_wrong_pin_fails_with_the_install_command(packages: dict[str, str | None]) -> None:
    packages["mujoco"] = "3.10.0"
    packages["robosuite"] = None
    checks = by_name(system.pin_checks())
    assert checks["version.mujoco"].status == "fail"
    assert checks["version.mujoco"].summary == "3.10.0, needs ==3.3.0"
    assert checks["version.mujoco"].fix.startswith("pip install 'mujoco==3.3.0'")
    assert checks["version.robosuite"].summary == "not installed, needs ==1.4.0"
    assert checks["version.robosuite"].fix.startswith("pip install --no-deps 'robosuite==1.4.0'")
    assert checks["version.libero"].status == "ok"


def test_an_unmet_requirement_is_named(packages: dict[str, str | None]) -> None:
    packages["numpy"] = "2.3.1"
    check = by_name(system.pin_checks())["requirements"]
    assert (check.status, check.summary) == ("fail", "1 unmet: numpy 2.3.1 (needs <2.3,>=1.26)")


def test_metadata_without_the_libero_extra_says_to_rerun_setup(
    packages: dict[str, str | None], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(system.metadata, "requires", lambda name: [r for r in REQUIRES if "libero" not in r])
    check = by_name(system.pin_checks())["version.libero"]
    assert check.status == "fail" and "predates this checkout" in check.summary
    assert "make setup" in check.fix


def test_vlaprobe_not_installed_is_one_failed_check(monkeypatch: pytest.MonkeyPatch) -> None:
    def missing(name: str) -> list[str]:
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(system.metadata, "requires", missing)
    check = timed("versions", lambda: system.pin_checks()[0])
    assert check.status == "fail" and "metadata is not installed" in check.summary


def test_the_installed_metadata_holds_the_pins_of_pyproject() -> None:
    """The real metadata: mujoco's pin is vlaprobe's (the libero extra appears once setup ran on this checkout)."""
    base, _ = system.requirements()
    assert "mujoco==3.3.0" in [str(r) for r in base]


def test_an_old_python_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(system.metadata, "metadata", lambda name: {"Requires-Python": ">=3.99"})
    check = system.python_check()
    assert check.status == "fail" and "does not satisfy >=3.99" in check.summary
    assert "Python >=3.99" in check.fix


def test_the_current_python_passes() -> None:
    assert system.python_check().status == "ok"


Usage = namedtuple("Usage", "total used free")


def test_disk_too_small_for_the_store_fails(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = DoctorConfig(out=tmp_path / "new" / "run", episodes=30)
    need = 30 * 2 * cfg.env.max_steps * system.row_bytes(33, 4096, "last_prompt")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: Usage(10**12, 0, need - 1))
    check = system.disk_check(cfg, (33, 4096))
    assert check.status == "fail" and check.figures["need_bytes"] == need
    assert check.figures["folder"] == str(tmp_path.resolve())  # the nearest folder that exists
    monkeypatch.setattr(shutil, "disk_usage", lambda path: Usage(10**12, 0, need))
    assert system.disk_check(cfg, (33, 4096)).status == "ok"
    assert (
        system.disk_check(DoctorConfig(out=tmp_path, control=False), (33, 4096)).figures["need_bytes"]
        == need // 2
    )


def test_the_store_estimate_grows_with_the_model_and_the_pooling() -> None:
    tiny, big = system.row_bytes(33, 64, "last_prompt"), system.row_bytes(33, 4096, "last_prompt")
    assert 25_000 < tiny < 40_000  # docs/collection.md: ~28 KB per step with the tiny model
    assert big - tiny == pytest.approx(33 * (4096 - 64) * 2 * system.HIDDEN_STORED, abs=1)
    assert system.row_bytes(33, 4096, "action_tokens") > 6 * big


def test_disk_without_the_model_size_warns(tmp_path: Path) -> None:
    assert system.disk_check(DoctorConfig(out=tmp_path), None).status == "warn"


def test_missing_tools_warn(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr(system, "CHROMIUM", tmp_path / "no-chromium")
    check = system.chromium_check()
    assert (check.status, check.fix) == ("warn", "apt install chromium")
    monkeypatch.setattr(system.shutil, "which", lambda name: None)
    check = system.tool_check(*system.TOOLS[0])
    assert (check.status, check.fix) == ("warn", "apt install swi-prolog-nox")


def test_a_gpu_asked_for_on_a_cpu_machine_fails() -> None:
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    cfg = DoctorConfig(policy=PolicyConfig(device="cuda"), env=EnvConfig())
    check = timed("torch", lambda: system.torch_check(cfg))
    assert check.status == "fail" and "CUDA is not available" in check.summary
    assert system.torch_check(DoctorConfig()).summary.endswith("runs on cpu in float32")
