"""Extra sections of the report page: a template and the data it renders, added after the figures.

A section comes either from the caller (``write_report(cfg, sections=[...])``: a higher package, such as the
cognition monitor, hands its own in; ``vlaprobe.pipeline`` does) or from a provider listed in
:data:`SECTION_PROVIDERS`: a ``"module:function"`` of this package called with the probe folder that returns a
:class:`Section` when its data exists there and None otherwise. Adding one is a template file plus one line here.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Section:
    """One extra section of the page."""

    id: str
    """HTML anchor (``index.html#<id>``) and the key of the section in the page's contents list."""
    title: str
    """The section's heading."""
    template: str
    """Template file name under the ``templates/`` folder of :attr:`package`; it sees ``section`` and ``data``."""
    data: object
    """What the template renders (a dataclass or the JSON of a file of the run)."""
    package: str = "vlaprobe.reports"
    """The package whose ``templates/`` folder holds :attr:`template` (a section ships its template with it)."""


SECTION_PROVIDERS: list[str] = [
    "vlaprobe.reports.compare:report_section",
    "vlaprobe.reports.sections:diversity_section",
    "vlaprobe.reports.sections:hypotheses_section",
    "vlaprobe.reports.sections:store_comparison_section",
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


def diversity_section(probes: Path) -> Section | None:
    """The diversity of the store the probes were trained on (if it is still there)."""
    from vlaprobe.collection.diversity import store_diversity
    from vlaprobe.errors import VlaprobeError
    from vlaprobe.probes.probemeta import read_probes_meta

    try:
        store = read_probes_meta(probes).store
    except VlaprobeError:
        return None
    if store is None or not (store / "zarr.json").is_file():
        return None
    d = store_diversity(store)
    rows = [
        {"head": head, "atom": a, "base_rate": r, "episodes_varying": n}
        for head, h in d.heads.items()
        for a, r, n in zip(h.atoms, h.base_rate, h.episodes_varying, strict=True)
        if n > 0
    ]
    return Section(
        id="diversity",
        title="How diverse the data are",
        template="diversity.html",
        data={"summary": d.as_dict(), "store": str(store), "varying": rows},
    )


def hypotheses_section(probes: Path) -> Section | None:
    """The H1/H2 section when ``hypotheses.json`` is in the probe folder."""
    from dataclasses import asdict

    from vlaprobe.probes.hypotheses_run import FILE, read_hypotheses

    if not (Path(probes) / FILE).is_file():
        return None
    return Section(
        id="hypotheses",
        title="H1 and H2: which layers encode objects and actions",
        template="hypotheses.html",
        data=asdict(read_hypotheses(probes)),
    )


def store_comparison_section(probes: Path) -> Section | None:
    """The stores side by side when ``vlaprobe compare-stores --probes`` wrote ``store_comparison.json`` there."""
    from vlaprobe.probes.store_compare import FILE, read_store_comparison

    if not (Path(probes) / FILE).is_file():
        return None
    data = read_store_comparison(probes).as_dict()
    return Section(id="stores", title="Stores side by side", template="store_comparison.html", data=data)
