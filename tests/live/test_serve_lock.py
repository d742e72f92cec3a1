"""Two servers recording into one folder: the second is refused before its model loads, naming the first."""

from __future__ import annotations

from pathlib import Path

import pytest
from tests.test_locks import held

from vlaprobe.configs.serve import ServeConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.live.serve import main, recordings_folder


def test_a_second_server_on_the_same_recordings_is_refused(fake_run: Path, tmp_path: Path) -> None:
    cfg = ServeConfig(probes=fake_run / "probes", port=0, recordings=tmp_path / "live")
    assert recordings_folder(cfg) == tmp_path / "live"
    assert recordings_folder(ServeConfig(probes=fake_run / "probes")) == fake_run / "live"
    with held(tmp_path / "live", "vlaprobe serve on port 6006") as proc, pytest.raises(VlaprobeError) as err:
        main(cfg)
    assert f"--recordings {tmp_path / 'live'} is being written by pid {proc.pid} (vlaprobe serve" in str(
        err.value
    )
