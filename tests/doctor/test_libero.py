"""The LIBERO checks: a missing asset fails the run's suite and warns for another, stand-ins are found and said
to change images, no assets folder at all fails, and LIBERO's init states load."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from tests.envs.test_assets import REAL_ASSETS, linked_copy

from vlaprobe.configs.doctor import DoctorConfig
from vlaprobe.configs.env import SUITES, EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.doctor import libero
from vlaprobe.doctor.libero import STAND_INS, assets_checks, libero_check, stand_ins, suite_files
from vlaprobe.envs.assets import ASSETS_ENV, SPATIAL_ASSETS


@pytest.fixture
def mirror(tmp_path: Path) -> Path:
    """The real assets folder (the shared copy, with its stand-ins) as links to its files: a test may remove or
    replace one."""
    if not REAL_ASSETS:
        pytest.skip("needs LIBERO's assets (VLAPROBE_LIBERO_ASSETS)")
    return linked_copy(tmp_path)


@pytest.fixture
def offline_copy(mirror: Path, shared_dir: Path) -> Path:
    """:func:`mirror` of the shared offline copy, the folder with the stand-ins."""
    if Path(str(REAL_ASSETS)).resolve() != (shared_dir / "libero_assets").resolve():
        pytest.skip("needs VLAPROBE_LIBERO_ASSETS to be the shared offline copy (its stand-ins)")
    return mirror


def config(folder: Path, model: str = "tiny-libero", suite: str = "libero_spatial") -> DoctorConfig:
    return DoctorConfig(policy=PolicyConfig(model=model), env=EnvConfig(suite=suite, assets=folder))  # type: ignore[arg-type]


def test_every_suite_is_complete_in_the_shared_folder_and_its_stand_ins_are_named(offline_copy: Path) -> None:
    checks = assets_checks(config(offline_copy))
    assert [c.name for c in checks] == [f"assets.{s}" for s in SUITES]
    assert {c.status for c in checks} == {"ok"}
    spatial = checks[0].figures["stand_ins"]
    assert sorted(spatial) == [
        "stable_scanned_objects/akita_black_bowl/texture.png",
        "stable_scanned_objects/akita_black_bowl/visual/akita_black_bowl_vis.msh",
        "stable_scanned_objects/plate/texture.png",
    ]
    assert "rendered images differ from LIBERO's" in checks[0].summary
    assert sorted(checks[-1].figures["stand_ins"]) == sorted(STAND_INS)  # LIBERO-90 loads all 16


def test_a_checkpoint_on_stand_ins_warns(offline_copy: Path) -> None:
    check = assets_checks(config(offline_copy, model="/ckpt/openvla-7b-finetuned-libero-spatial"))[0]
    assert check.status == "warn" and ASSETS_ENV in check.fix


def test_a_missing_asset_fails_the_runs_suite_and_warns_for_the_others(mirror: Path) -> None:
    (mirror / "stable_scanned_objects/plate/texture.png").unlink()  # used by spatial, goal, 10 and 90
    checks = {c.name: c for c in assets_checks(config(mirror))}
    spatial = checks["assets.libero_spatial"]
    assert spatial.status == "fail"
    assert "is missing a file of libero_spatial: stable_scanned_objects/plate/texture.png" in spatial.summary
    assert "restore it" in spatial.fix
    assert checks["assets.libero_goal"].status == "warn"
    assert checks["assets.libero_object"].status == "ok"  # no plate there
    goal = {c.name: c for c in assets_checks(config(mirror, suite="libero_goal"))}
    assert goal["assets.libero_goal"].status == "fail" and goal["assets.libero_spatial"].status == "warn"


def test_a_replaced_stand_in_is_an_original(offline_copy: Path) -> None:
    mirror = offline_copy
    texture = mirror / "stable_scanned_objects/plate/texture.png"
    content = texture.read_bytes()
    texture.unlink()
    texture.write_bytes(
        content[:40] + bytes([content[40] ^ 0xFF]) + content[41:]
    )  # one byte in, the PNG frame kept
    files = suite_files(mirror, SPATIAL_ASSETS)
    assert texture in files
    assert "stable_scanned_objects/plate/texture.png" not in stand_ins(mirror, files)
    assert len(stand_ins(mirror, files)) == 2


def test_no_assets_folder_fails_with_the_fix(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(ASSETS_ENV, raising=False)
    monkeypatch.setattr(libero.importlib.util, "find_spec", lambda name: None)
    [check] = assets_checks(DoctorConfig())
    assert check.status == "fail" and check.summary == "no assets folder is set or installed"
    assert ASSETS_ENV in check.fix
    [check] = assets_checks(config(tmp_path / "nowhere"))
    assert check.status == "fail" and "is not a folder" in check.summary


def test_the_environment_variable_names_the_folder(mirror: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(ASSETS_ENV, str(mirror))
    assert libero.assets_folder(DoctorConfig()) == (mirror.resolve(), ASSETS_ENV)
    assert os.environ[ASSETS_ENV] == str(mirror)


@pytest.mark.libero
def test_libero_imports_and_loads_its_init_states() -> None:
    check = libero_check(DoctorConfig())
    assert check.status == "ok" and check.figures == {"tasks": 10, "init_states": 50}
