"""The output-folder lock: a second writer (another process) is refused naming the holder, a holder killed with
``kill -9`` is taken over, and a released lock leaves nothing behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from vlaprobe.errors import VlaprobeError
from vlaprobe.locks import lock_folder, lock_path

REPO = Path(__file__).resolve().parents[1]
HOLD = """
import sys, time
from vlaprobe.locks import lock_folder
lock = lock_folder(sys.argv[1], command=sys.argv[2])
print("locked", flush=True)
time.sleep(600)
"""


@contextmanager
def held(out: Path, command: str = "vlaprobe collect --out X") -> Iterator[subprocess.Popen[str]]:
    """Another process holding the lock of ``out`` until the block ends (killed then, with SIGKILL)."""
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{REPO / 'src'}"}
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(out), command], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
        yield proc
    finally:
        proc.kill()
        proc.wait(timeout=10)


def test_a_second_process_is_refused_with_the_holders_pid_and_command(tmp_path: Path) -> None:
    out = tmp_path / "store"
    with held(out, "vlaprobe collect --out store --tasks 0") as proc:
        with pytest.raises(VlaprobeError) as err:
            lock_folder(out)
        message = str(err.value)
        assert (
            f"--out {out} is being written by pid {proc.pid} (vlaprobe collect --out store --tasks 0)"
            in message
        )
        assert "\n" not in message and "use another --out" in message


def test_a_lock_of_a_killed_holder_is_taken_over(tmp_path: Path) -> None:
    out = tmp_path / "store"
    with held(out) as proc:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        assert lock_path(out).exists()  # the stale file is still there, its lock is not
        with lock_folder(out, command="second") as lock:
            assert lock.held and lock_path(out).read_text() == f"{os.getpid()}\nsecond\n"
            with pytest.raises(VlaprobeError, match=f"pid {os.getpid()} \\(second\\)"):
                lock_folder(out)


def test_release_removes_the_lock_file_and_the_parents_it_made(tmp_path: Path) -> None:
    out = tmp_path / "a" / "b" / "store"
    with lock_folder(out):
        assert lock_path(out).is_file()
    assert not (tmp_path / "a").exists()
    (tmp_path / "a").mkdir()
    with lock_folder(out):
        out.mkdir()  # the command wrote its folder: the parents stay
    assert out.is_dir() and not lock_path(out).exists()
