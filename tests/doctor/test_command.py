"""``vlaprobe doctor`` end to end: exit codes, the lines, the JSON object's schema, bad flags, the model check."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from vlaprobe.cli import main
from vlaprobe.configs.doctor import DoctorConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.doctor import command
from vlaprobe.doctor.policy import policy_check
from vlaprobe.doctor.report import FORMAT, Check, Status, line, timed

CHECK_KEYS = {"name", "status", "summary", "fix", "seconds", "figures"}


def canned(
    monkeypatch: pytest.MonkeyPatch, bad: dict[str, Status] | None = None, render: bool = False
) -> None:
    """Every check replaced by an ok one (``bad``: name -> another status), so only the command is tested; with
    ``render`` the renderer backends really run."""
    bad = bad or {}

    def ok(name: str) -> Check:
        status = bad.get(name, "ok")
        return Check(name, status, f"{name} is {status}", "" if status == "ok" else f"fix {name}")

    monkeypatch.setattr(command, "python_check", lambda: ok("python"))
    monkeypatch.setattr(command, "pin_checks", lambda: [ok("version.mujoco"), ok("requirements")])
    monkeypatch.setattr(command, "torch_check", lambda cfg: ok("torch"))
    monkeypatch.setattr(command, "libero_check", lambda cfg: ok("libero"))
    monkeypatch.setattr(command, "assets_checks", lambda cfg: [ok("assets.libero_spatial")])
    monkeypatch.setattr(command, "policy_check", lambda cfg: (ok("policy"), (33, 64)))
    monkeypatch.setattr(command, "disk_check", lambda cfg, dims: ok("disk"))
    monkeypatch.setattr(command, "chromium_check", lambda: ok("chromium"))
    monkeypatch.setattr(command, "tool_check", lambda name, *args: ok(name))
    if not render:
        monkeypatch.setattr(command, "backend_in_use", lambda: "osmesa")
        monkeypatch.setattr(command, "start_backends", lambda backends, timeout: {})
        monkeypatch.setattr(command, "renderer_checks", lambda runs, in_use: [ok("renderer.osmesa")])


def run_json(capsys: pytest.CaptureFixture[str], *flags: str) -> tuple[int, dict]:
    code = main(["doctor", "--json", *flags])
    return code, json.loads(capsys.readouterr().out)


def test_all_ok_exits_0_with_one_line_per_check(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    canned(monkeypatch)
    assert main(["doctor"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 13 and all(line.startswith("✓ ") for line in lines[:-1])
    assert lines[-1].startswith("doctor: 12 checks, 0 failed, 0 warnings in ")
    assert lines[-1].endswith("ready for `vlaprobe run` with these settings")


def test_a_warning_still_exits_0_and_a_failure_exits_1(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    canned(monkeypatch, {"chromium": "warn"})
    code, out = run_json(capsys)
    assert (code, out["ready"]) == (0, True)
    canned(monkeypatch, {"chromium": "warn", "assets.libero_spatial": "fail"})
    code, out = run_json(capsys)
    assert (code, out["ready"]) == (1, False)
    failed = [c for c in out["checks"] if c["status"] == "fail"]
    assert failed == [
        {"name": "assets.libero_spatial", "status": "fail", "summary": "assets.libero_spatial is fail",
         "fix": "fix assets.libero_spatial", "seconds": failed[0]["seconds"], "figures": {}}
    ]  # fmt: skip


def test_the_json_object_has_its_schema(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    canned(monkeypatch)
    _, out = run_json(capsys)
    assert set(out) == {"format", "format_version", "ready", "seconds", "checks"}
    assert (out["format"], out["format_version"]) == (FORMAT, 1)
    assert isinstance(out["seconds"], float) and out["seconds"] >= 0
    for check in out["checks"]:
        assert set(check) == CHECK_KEYS
        assert check["status"] in ("ok", "warn", "fail", "skip")
        assert isinstance(check["seconds"], float) and isinstance(check["figures"], dict)
    names = [c["name"] for c in out["checks"]]
    assert names[:3] == ["python", "version.mujoco", "requirements"] and len(set(names)) == len(names)


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--episodes", "-1"], "--episodes must be at least 0"),
        (["--timeout", "0"], "--timeout must be a positive number"),
        (["--renderers"], "--renderers"),
        (["--renderers", "vulkan"], "vulkan"),
        (["--device", "tpu"], "device"),
        (["--env.max-steps", "0"], "--env.max-steps must be at least 1"),
        (["--suite", "libero_100"], "invalid choice 'libero_100'"),
    ],
)
def test_bad_flags_exit_2_with_one_line(
    flags: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["doctor", *flags]) == 2
    err = capsys.readouterr().err
    assert err.startswith("vlaprobe: error: ") and message in err and len(err.strip().splitlines()) == 1


def test_a_bogus_mujoco_gl_fails_the_renderer_a_run_would_use(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    canned(monkeypatch, render=True)
    monkeypatch.setenv("MUJOCO_GL", "bogus")  # what a run would use: tried in a subprocess with the others
    code, out = run_json(capsys, "--renderers", "glx")
    checks = {c["name"]: c for c in out["checks"]}
    assert code == 1
    assert checks["renderer.bogus"]["status"] == "fail"
    assert checks["renderer.bogus"]["summary"].endswith(
        "invalid value for environment variable MUJOCO_GL: bogus"
    )
    assert checks["renderer.glx"]["status"] in ("ok", "warn")  # without an X display: a warning
    assert checks["renderer.compare"]["status"] == "skip"


def test_an_unloadable_model_fails_the_policy_check(tmp_path: Path) -> None:
    cfg = DoctorConfig(policy=PolicyConfig(model=str(tmp_path / "no-such-checkpoint")))
    check = timed("policy", lambda: policy_check(cfg)[0])
    assert check.status == "fail" and "no-such-checkpoint" in check.summary
    assert "\n" not in line(check)


def test_the_policy_check_times_a_step_with_and_without_capture() -> None:
    check, dims = policy_check(DoctorConfig(policy=PolicyConfig(model="tiny", device="cpu")))
    assert check.status == "ok" and dims is not None and dims[0] == 33
    f = check.figures
    assert f["hidden_shape"] == [33, dims[1]] and f["device"] == "cpu" and f["dtype"] == "float32"
    assert f["step_seconds"] > 0 and f["step_seconds_no_capture"] > 0
    assert f["capture_overhead"] == pytest.approx(
        f["step_seconds"] / f["step_seconds_no_capture"] - 1, abs=0.01
    )


@pytest.mark.heavy
@pytest.mark.libero
def test_the_real_doctor_on_this_machine(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """Every check for real (one renderer backend, to stay short): the schema, and what this machine must pass."""
    code, out = run_json(capsys, "--renderers", "osmesa", "--out", str(tmp_path / "run"))
    checks = {c["name"]: c for c in out["checks"]}
    assert code == (0 if out["ready"] else 1)
    for name in ("python", "torch", "libero", "assets.libero_spatial", "policy", "disk", "version.mujoco"):
        assert checks[name]["status"] == "ok", checks[name]
    assert checks["policy"]["figures"]["hidden_shape"] == [33, 64]
    assert {"renderer.osmesa", "renderer.compare", "chromium", "prolog", "compiler"} <= set(checks)
