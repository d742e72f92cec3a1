"""envs/setup.py: LIBERO's config is written per LIBERO install, so two checkouts never rewrite each other's."""

from __future__ import annotations

import importlib.machinery
import os
from pathlib import Path

import pytest

from vlaprobe.envs import setup


def _install(tmp_path: Path, name: str, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A fake LIBERO package under ``tmp_path/name`` that ``importlib.util.find_spec("libero")`` finds."""
    package = tmp_path / name / "libero"
    (package / "libero").mkdir(parents=True, exist_ok=True)
    spec = importlib.machinery.ModuleSpec("libero", None, is_package=True)
    spec.submodule_search_locations = [str(package)]
    monkeypatch.setattr("importlib.util.find_spec", lambda module: spec if module == "libero" else None)
    monkeypatch.delenv("LIBERO_CONFIG_PATH", raising=False)
    setup._write_libero_config()
    return Path(os.environ["LIBERO_CONFIG_PATH"]) / "config.yaml"


def test_two_installs_keep_their_own_config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    first = _install(tmp_path, "checkout-a", monkeypatch)
    second = _install(tmp_path, "checkout-b", monkeypatch)
    assert first != second
    assert f"benchmark_root: {tmp_path / 'checkout-a' / 'libero' / 'libero'}\n" in first.read_text()
    assert f"benchmark_root: {tmp_path / 'checkout-b' / 'libero' / 'libero'}\n" in second.read_text()
    assert _install(tmp_path, "checkout-a", monkeypatch) == first  # the same install: the same folder
