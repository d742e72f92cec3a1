"""Extra sections of the report page: a template and the data it renders, added after the figures.

A section comes either from the caller (``write_report(cfg, sections=[...])``) or from a provider listed in
:data:`SECTION_PROVIDERS`: a ``"module:function"`` called with the probe folder that returns a
:class:`Section` when its data exists there (e.g. the cognition monitor's ``monitor.json``) and None
otherwise. Adding one is a template file (in ``vlaprobe/reports/templates/`` or ``vlaprobe/cognition/templates/``)
plus one line here.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass
class Section:
    """One extra section of the page."""

    id: str
    """HTML anchor (``index.html#<id>``) and the key of the section in the page's contents list."""
    title: str
    """The section's heading."""
    template: str
    """Template file name under ``vlaprobe/reports/templates/`` or ``vlaprobe/cognition/templates/`` (the
    page's loader searches both); it sees ``section`` and ``data``."""
    data: Any
    """What the template renders (a dataclass, typically read from a JSON file of the run)."""


SECTION_PROVIDERS: list[str] = [
    "vlaprobe.reports.compare:report_section",
    "vlaprobe.cognition.monitor:report_section",
    "vlaprobe.collection.diversity:report_section",
    "vlaprobe.probes.store_compare:report_section",
    "vlaprobe.probes.hypotheses_run:report_section",
]
"""``"module:function"`` providers, each ``(probes_folder: Path) -> Section | None``, in page order."""


def find_sections(probes: Path) -> list[Section]:
    """The sections the registered providers find for this probe folder."""
    found = []
    for spec in SECTION_PROVIDERS:
        module, name = spec.split(":")
        section = getattr(importlib.import_module(module), name)(probes)
        if section is not None:
            found.append(section)
    return found
