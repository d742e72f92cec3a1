"""The web UI shipped in the package (src/vlaprobe/live/ui) is built from the current web/ sources."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
WEB = REPO / "web"
UI = REPO / "src" / "vlaprobe" / "live" / "ui"
TOP_FILES = ("index.html", "package.json", "package-lock.json", "tsconfig.json", "vite.config.ts")


def sources_hash() -> str:
    """What scripts/build_web.sh hashes: sha256 of the `sha256sum`-style lines of the sources, in byte order."""
    files = [p.relative_to(WEB).as_posix() for p in (WEB / "src").rglob("*") if p.is_file()]
    files = sorted(files + list(TOP_FILES), key=lambda s: s.encode())
    lines = "".join(f"{hashlib.sha256((WEB / f).read_bytes()).hexdigest()}  {f}\n" for f in files)
    return hashlib.sha256(lines.encode()).hexdigest()


def test_shipped_build_is_current() -> None:
    stamp = (UI / "BUILD_STAMP").read_text().strip()
    assert stamp == sources_hash(), "web/ changed since the UI was built: run `bash scripts/build_web.sh`"


def test_index_references_shipped_assets() -> None:
    html = (UI / "index.html").read_text()
    assets = re.findall(r'(?:src|href)="\./(assets/[^"]+)"', html)
    assert any(a.endswith(".js") for a in assets) and any(a.endswith(".css") for a in assets)
    for a in assets:
        assert (UI / a).is_file(), a
    shipped = {p.relative_to(UI).as_posix() for p in (UI / "assets").iterdir()}
    assert shipped == {a for a in assets}, "stale files in src/vlaprobe/live/ui/assets"
