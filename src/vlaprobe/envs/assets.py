"""Check a LIBERO assets folder before anything is built from it: every file a suite loads, cheaply.

A missing texture, a missing or truncated mesh or a malformed XML otherwise surfaces as a MuJoCo/XML traceback
deep inside robosuite, after the model has been loaded. :func:`check_assets` reads the XML files the suite's
scenes are built from (:class:`AssetFiles`: LIBERO-spatial's seven are :data:`SPATIAL_ASSETS`; any suite's come
from its BDDL files, ``vlaprobe.envs.suite_assets``), follows every file they reference (meshes, textures) the
way robosuite resolves them (relative to the referencing XML's folder), and checks each file's structure from
its header and tail without decoding it: ~30 files for LIBERO-spatial, a few milliseconds.

What each check catches:
- XML: parses (``xml.etree``); a syntax error names the line.
- ``.msh`` (MuJoCo's binary mesh): the size its header announces (4 int32 counts: vertices, normals,
  texture coordinates, faces) equals the file's size.
- ``.stl``: binary (the 80-byte header's triangle count x 50 bytes + 84) or ASCII (``solid`` ... ``endsolid``).
- ``.png``: the PNG signature at the start and the ``IEND`` chunk at the end (a cut file lacks it).
- anything else: not empty.
"""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from vlaprobe.errors import VlaprobeError

ASSETS_ENV = "VLAPROBE_LIBERO_ASSETS"

SPATIAL_XML_FILES: tuple[str, ...] = (
    "scenes/libero_tabletop_base_style.xml",
    "articulated_objects/wooden_cabinet.xml",
    "articulated_objects/flat_stove.xml",
    "stable_scanned_objects/akita_black_bowl/akita_black_bowl.xml",
    "stable_scanned_objects/plate/plate.xml",
    "stable_hope_objects/cookies/cookies.xml",
    "stable_scanned_objects/glazed_rim_porcelain_ramekin/glazed_rim_porcelain_ramekin.xml",
)
"""The XML files LIBERO-spatial's scene is built from, relative to the assets folder."""

STYLED_TEXTURES: dict[str, str] = {
    "texplane": "light-gray-floor-tile.png",
    "tex-wall": "light-gray-plaster.png",
}
"""Textures whose file LIBERO's ``TableArena`` swaps for its style's (same folder, other name): the floor and wall
styles LIBERO-spatial's problem class selects ("light-gray", "light-gray-plaster")."""


@dataclass(frozen=True)
class AssetFiles:
    """What a suite's scenes load: XML files (relative to the assets folder) and, per scene XML, the textures its
    arena swaps for its style's file (texture name -> file name in the same folder)."""

    xml: tuple[str, ...]
    styled: Mapping[str, Mapping[str, str]] = field(default_factory=dict)


SPATIAL_ASSETS = AssetFiles(SPATIAL_XML_FILES, {SPATIAL_XML_FILES[0]: STYLED_TEXTURES})
"""LIBERO-spatial's files (``tests/envs/test_assets.py`` pins them equal to what its BDDL files name)."""

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_END = b"IEND\xaeB`\x82"  # the IEND chunk's type and CRC: the last 8 bytes of every complete PNG


FIX = f"restore it from a complete copy of LIBERO's assets, or point {ASSETS_ENV} (or --env.assets) at one"


def referenced_files(xml_path: Path, styled: Mapping[str, str] = STYLED_TEXTURES) -> list[Path]:
    """Files an asset XML references (``file*`` attributes), resolved as robosuite does; ``styled`` textures
    (name -> file) swapped.

    When two assets share a tag and a name only the first is loaded (robosuite's ``merge_assets`` skips names it
    already holds): LIBERO's ``flat_stove.xml`` names a second ``tex-stove_knob`` whose file does not exist.
    """
    root = ET.parse(xml_path).getroot()
    files = []
    seen: set[tuple[str, str]] = set()
    for node in root.iter():
        name = node.get("name")
        if name is not None:
            if (node.tag, name) in seen:
                continue
            seen.add((node.tag, name))
        for key, value in node.attrib.items():
            if not key.startswith("file") or not value:
                continue
            path = xml_path.parent / value
            if node.tag == "texture" and name is not None and name in styled:
                path = path.with_name(styled[name])
            files.append(path)
    return files


def file_problem(path: Path) -> str | None:
    """Why ``path`` cannot be loaded (missing, empty, cut short, malformed), or None when it looks whole."""
    if not path.is_file():
        return "is missing"
    size = path.stat().st_size
    if size == 0:
        return "is empty"
    suffix = path.suffix.lower()
    with path.open("rb") as f:
        head = f.read(84)
        f.seek(max(0, size - 256))
        tail = f.read()  # where a PNG's end chunk or an ASCII STL's "endsolid" stands
    if suffix == ".msh":
        if size < 16:
            return f"is cut short ({size} bytes, no complete header)"
        nv, nn, nt, nf = struct.unpack("<4i", head[:16])
        expected = 16 + 12 * nv + 12 * nn + 8 * nt + 12 * nf
        if min(nv, nn, nt, nf) < 0 or expected != size:
            return f"is cut short or damaged ({size} bytes; its header announces {expected})"
    elif suffix == ".stl":
        binary = len(head) == 84 and 84 + 50 * struct.unpack("<I", head[80:84])[0] == size
        ascii_ = head.lstrip().startswith(b"solid") and b"endsolid" in tail
        if not binary and not ascii_:
            return f"is cut short or damaged ({size} bytes, neither a whole binary nor ASCII STL)"
    elif suffix == ".png":
        if not head.startswith(PNG_SIGNATURE):
            return "is not a PNG image"
        if not tail.endswith(PNG_END):
            return f"is cut short ({size} bytes, no end chunk)"
    elif suffix == ".xml":
        try:
            ET.parse(path)
        except ET.ParseError as err:
            return f"is not valid XML ({err})"
    return None


def check_assets(folder: Path, files: AssetFiles = SPATIAL_ASSETS, suite: str = "libero_spatial") -> None:
    """Raise a one-line :class:`VlaprobeError` naming the first file of ``folder`` that ``suite`` (its ``files``)
    cannot load."""
    for rel in files.xml:
        xml_path = folder / rel
        problem = file_problem(xml_path)
        if problem is not None:
            what = "is missing a file" if problem == "is missing" else "is damaged"
            raise VlaprobeError(f"LIBERO assets folder {folder} {what} of {suite}: {rel} {problem}; {FIX}")
        for path in referenced_files(xml_path, files.styled.get(rel, {})):
            problem = file_problem(path)
            if problem is not None:
                shown = path.resolve().relative_to(folder) if path.resolve().is_relative_to(folder) else path
                what = "is missing a file" if problem == "is missing" else "is damaged"
                raise VlaprobeError(
                    f"LIBERO assets folder {folder} {what} of {suite}: {shown} (used by {rel}) {problem}; {FIX}"
                )
