"""The renderer checks: a backend that cannot load, one that hangs, one that renders; the images compared."""

from __future__ import annotations

import ctypes.util

import numpy as np
import pytest

from vlaprobe.doctor import render
from vlaprobe.doctor.render import BackendRun, compare_check, renderer_checks, run_backend

needs_osmesa = pytest.mark.skipif(not ctypes.util.find_library("OSMesa"), reason="needs libosmesa6")


def rendered(backend: str, image: np.ndarray) -> BackendRun:
    figures = {"first_seconds": 0.5, "render_ms": 3.0, "gl_renderer": "llvmpipe", "mujoco": "3.3.0"}
    return BackendRun(backend, 1.0, figures, image, "")


def failed(backend: str, error: str = "RuntimeError: no display") -> BackendRun:
    return BackendRun(backend, 1.0, {}, None, error)


def test_an_unknown_backend_fails_in_its_subprocess_with_mujocos_reason() -> None:
    run = run_backend("bogus", timeout=120)
    assert run.image is None
    assert run.error == "RuntimeError: invalid value for environment variable MUJOCO_GL: bogus"


def test_a_backend_that_does_not_answer_in_time_is_ended() -> None:
    run = run_backend("osmesa", timeout=0.05)  # the interpreter alone takes longer to start
    assert run.image is None and run.error.startswith("no image within 0.05 s")


def test_an_interpreter_that_cannot_start_is_a_failed_backend(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(render.sys, "executable", "/no/such/python")
    run = run_backend("osmesa", timeout=120)
    assert run.image is None and run.error == "cannot start /no/such/python: No such file or directory"


@needs_osmesa
def test_osmesa_renders_the_scene_and_reports_its_timing() -> None:
    run = run_backend("osmesa", timeout=120)
    assert run.error == ""
    assert run.image is not None and run.image.shape == (128, 128, 3) and run.image.std() > 10
    assert run.figures["render_ms"] > 0 and run.figures["mujoco"]
    [check, compare] = renderer_checks({"osmesa": run}, in_use="osmesa")
    assert check.status == "ok" and "(what a run uses)" in check.summary
    assert compare.status == "skip"


def test_the_backend_in_use_failing_fails_the_doctor_and_names_one_that_works() -> None:
    image = np.zeros((4, 4, 3), np.uint8)
    checks = renderer_checks({"osmesa": failed("osmesa"), "egl": rendered("egl", image)}, in_use="osmesa")
    assert [(c.name, c.status) for c in checks] == [
        ("renderer.osmesa", "fail"),
        ("renderer.egl", "ok"),
        ("renderer.compare", "skip"),
    ]
    assert checks[0].fix == "apt install libosmesa6, or set MUJOCO_GL=egl (it renders here)"


def test_another_backend_failing_only_warns() -> None:
    image = np.zeros((4, 4, 3), np.uint8)
    checks = renderer_checks({"egl": rendered("egl", image), "glx": failed("glx")}, in_use="egl")
    assert [c.status for c in checks] == ["ok", "warn", "skip"]
    assert checks[1].fix.startswith(render.FIXES["glx"])


def test_identical_renders_pass_and_different_ones_warn() -> None:
    image = np.random.default_rng(0).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    same = compare_check(
        {"osmesa": rendered("osmesa", image), "egl": rendered("egl", image.copy())}, "osmesa"
    )
    assert same.status == "ok" and same.figures["egl"] == {
        "mean_abs": 0.0,
        "max_abs": 0,
        "share_differing": 0.0,
    }
    other = image.copy()
    other[:2] = 255 - other[:2]  # a quarter of the rows
    differ = compare_check({"osmesa": rendered("osmesa", image), "egl": rendered("egl", other)}, "osmesa")
    assert differ.status == "warn" and "MUJOCO_GL=osmesa" in differ.fix
    assert 0.2 <= differ.figures["egl"]["share_differing"] <= 0.25
