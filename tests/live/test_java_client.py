"""The JDK-only DIARC client, compiled and run against a real server on 127.0.0.1 (skipped without a JDK)."""

from __future__ import annotations

import json
import shutil
import subprocess
import urllib.request
from pathlib import Path

import pytest
from tests.live.fakes import FAIL_INIT, SUCCESS_INIT, LiveServer, real_engine

from vlaprobe.configs.serve import ServeConfig
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.live.app import Limits, create_app

CLIENT = Path(__file__).resolve().parents[2] / "clients" / "diarc" / "src"
pytestmark = [
    pytest.mark.timeout(180),
    pytest.mark.skipif(
        not (shutil.which("javac") and shutil.which("java")), reason="no JDK (javac, java) found"
    ),
]


@pytest.fixture(scope="module")
def classes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("classes")
    sources = sorted(str(p) for p in CLIENT.rglob("*.java"))
    subprocess.run(["javac", "-Xlint:all", "-Werror", "-d", str(out), *sources], check=True, timeout=120)
    return out


def test_java_client_follows_an_episode_and_keeps_the_beliefs(
    classes: Path, fake_run: Path, tmp_path: Path
) -> None:
    cfg = ServeConfig(probes=fake_run / "probes", recordings=tmp_path / "live")
    engine = real_engine(cfg)
    app = create_app(engine, Limits(token="tok"))
    with LiveServer(app) as srv:
        args = ["java", "-cp", str(classes), "vlaprobe.diarc.LiveClient", srv.url, "--token", "tok"]
        run = subprocess.run(
            [*args, "--start", "0", "--init", str(SUCCESS_INIT), "--once"],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert run.returncode == 0, run.stderr
        request = urllib.request.Request(f"{srv.http}/api/episodes", headers={"Authorization": "Bearer tok"})
        episode_id = json.loads(urllib.request.urlopen(request, timeout=10).read())[0]["id"]
        request = urllib.request.Request(
            f"{srv.http}/api/episodes/{episode_id}", headers={"Authorization": "Bearer tok"}
        )
        record = json.loads(urllib.request.urlopen(request, timeout=10).read())
        refused = subprocess.run([*args[:-2], "--once"], capture_output=True, text=True, timeout=60)
    beliefs: set[str] = set()
    for step in record["steps"]:
        beliefs = (beliefs - set(step["beliefs"]["retracted"])) | set(step["beliefs"]["asserted"])
    lines = run.stdout.splitlines()
    assert f"END {episode_id} success=true steps={len(record['steps'])}" in lines
    final = next(line for line in lines if line.startswith("BELIEFS"))
    assert set(final.split()[1:]) == beliefs and beliefs
    assert any(line.startswith("ASSERT ") for line in lines)
    assert refused.returncode != 0  # no token: the server refuses the connection


def test_java_client_reads_the_alarm_and_the_handovers(classes: Path, fake_run: Path, tmp_path: Path) -> None:
    takeover = TakeoverConfig(takeover="alarm", takeover_stall=4, takeover_steps=3)
    cfg = ServeConfig(
        probes=fake_run / "probes", recordings=tmp_path / "live", driver="policy", intervention=takeover
    )
    with LiveServer(create_app(real_engine(cfg), Limits())) as srv:
        start = ["--start", "0", "--init", str(FAIL_INIT), "--driver", "policy", "--once"]
        run = subprocess.run(
            ["java", "-cp", str(classes), "vlaprobe.diarc.LiveClient", srv.url, *start],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert run.returncode == 0, run.stderr
        episode_id = json.loads(urllib.request.urlopen(f"{srv.http}/api/episodes", timeout=10).read())[0][
            "id"
        ]
        url = f"{srv.http}/api/episodes/{episode_id}"
        steps = json.loads(urllib.request.urlopen(url, timeout=10).read())["steps"]
    expected = []
    for s in steps:
        if (a := s["alarm"]) is not None:
            expected.append(
                f"ALARM t={s['t']} {a['kind']}: {a['reason']} rules=[{', '.join(a['rules'])}] atoms=[{', '.join(a['atoms'])}]"
            )
        if s["handover"] == "to_expert":
            expected.append(f"HANDOVER t={s['t']} to_expert ({s['takeover']['reason']})")
        elif s["handover"] == "to_policy":
            expected.append(f"HANDOVER t={s['t']} to_policy")
    assert any(line.startswith("HANDOVER") for line in expected), "no takeover: the test proves nothing"
    assert [line for line in run.stdout.splitlines() if line.startswith(("ALARM", "HANDOVER"))] == expected
