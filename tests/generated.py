"""Tables the docs carry between two markers, written by the test that checks them (never by hand)."""

from __future__ import annotations

import re
from pathlib import Path


def doc_with(text: str, doc: str, begin: str, end: str, where: Path) -> str:
    """``doc`` with what lies between ``begin`` and ``end`` replaced by ``text`` (``where`` names the file in
    the failure when the markers are missing)."""
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    assert pattern.search(doc), f"{where} has no generated table ({begin})"
    return pattern.sub(lambda _: f"{begin}\n{text}\n{end}", doc)
