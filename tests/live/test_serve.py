"""`vlaprobe serve`'s checks before it listens: token off loopback, probes present, port free, rates."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from vlaprobe.cli import main as cli
from vlaprobe.configs.checks import check_serve
from vlaprobe.configs.serve import ServeConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.live.serve import _listen, limits_of, load_probes, resolve_token


def test_token_is_required_off_loopback(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("VLAPROBE_TOKEN", raising=False)
    assert resolve_token(ServeConfig()) is None
    assert resolve_token(ServeConfig(host="::1")) is None
    for host in ("0.0.0.0", "192.168.1.5", "example.org"):
        with pytest.raises(VlaprobeError, match="VLAPROBE_TOKEN or a --token-file"):
            resolve_token(ServeConfig(host=host))
    assert resolve_token(ServeConfig(host="0.0.0.0", token="t")) == "t"
    monkeypatch.setenv("VLAPROBE_TOKEN", "from-env")
    assert resolve_token(ServeConfig(host="0.0.0.0")) == "from-env"


def test_without_probes_one_line_says_what_to_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(VlaprobeError, match="run `vlaprobe run` first"):
        load_probes(ServeConfig(probes=tmp_path / "none"))
    assert cli(["serve", "--probes", str(tmp_path / "none"), "--port", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vlaprobe: error: no probes in")


def test_busy_port_and_bad_rates() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        with pytest.raises(VlaprobeError, match="pass another --port"):
            _listen("127.0.0.1", s.getsockname()[1])
    for bad, match in (
        (dict(image_hz=0), "--image-hz"),
        (dict(replay_hz=0.1), "--replay-hz"),
        (dict(replay_hz=1000), "--replay-hz"),
        (dict(port=70000), "--port"),
        (dict(port=-1), "--port"),
        (dict(max_message_bytes=-1), "--max-message-bytes"),
    ):
        with pytest.raises(VlaprobeError, match=match):
            check_serve(ServeConfig(**bad))


def test_token_from_a_file_or_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VLAPROBE_TOKEN", "from-env")
    secret = tmp_path / "token"
    secret.write_text("from-file\n")
    assert resolve_token(ServeConfig(host="0.0.0.0", token_file=secret)) == "from-file"
    assert (
        limits_of(ServeConfig(host="0.0.0.0"), resolve_token(ServeConfig(host="0.0.0.0"))).token == "from-env"
    )
    secret.write_text("")
    with pytest.raises(VlaprobeError, match="is empty"):
        resolve_token(ServeConfig(token_file=secret))
    with pytest.raises(VlaprobeError, match="both given"):
        check_serve(ServeConfig(token="x", token_file=secret))
