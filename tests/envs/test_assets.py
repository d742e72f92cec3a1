"""The LIBERO assets check: a damaged folder is one line naming the file and the fix, before anything is built."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import pytest

from vlaprobe.configs.env import SUITES
from vlaprobe.configs.suite import TasksConfig
from vlaprobe.envs.assets import (
    PNG_END,
    PNG_SIGNATURE,
    SPATIAL_ASSETS,
    SPATIAL_XML_FILES,
    check_assets,
    referenced_files,
)
from vlaprobe.envs.setup import prepare_libero, resolve_assets
from vlaprobe.envs.suite import tasks
from vlaprobe.errors import VlaprobeError

REAL_ASSETS = os.environ.get("VLAPROBE_LIBERO_ASSETS")


def msh(nv: int = 3, nf: int = 1) -> bytes:
    """A MuJoCo binary mesh: header (vertices, normals, texcoords, faces), then the arrays."""
    return struct.pack("<4i", nv, 0, 0, nf) + bytes(12 * nv + 12 * nf)


def stl(triangles: int = 2) -> bytes:
    return bytes(80) + struct.pack("<I", triangles) + bytes(50 * triangles)


PNG = PNG_SIGNATURE + bytes(30) + b"\x00\x00\x00\x00" + PNG_END


@pytest.fixture
def assets(tmp_path: Path) -> Path:
    """A small assets folder shaped like LIBERO's: the seven XML files, each with a mesh and a texture."""
    root = tmp_path / "assets"
    for k, rel in enumerate(SPATIAL_XML_FILES):
        xml = root / rel
        (xml.parent / "parts").mkdir(parents=True, exist_ok=True)
        mesh = "parts/wall.stl" if k == 0 else f"parts/m{k}.msh"
        # The scene's floor texture is swapped by LIBERO's TableArena for its style's file in the same folder.
        extra = '<texture name="texplane" file="../textures/unused_style.png"/>' if k == 0 else ""
        xml.write_text(
            f'<mujoco><asset><mesh name="m" file="{mesh}"/><texture name="t" file="parts/t{k}.png"/>'
            f'<texture name="t" file="parts/duplicate_name_never_loaded.png"/>{extra}</asset></mujoco>'
        )
        (xml.parent / mesh).write_bytes(stl() if k == 0 else msh())
        (xml.parent / f"parts/t{k}.png").write_bytes(PNG)
    (root / "textures").mkdir()
    (root / "textures/light-gray-floor-tile.png").write_bytes(PNG)
    return root


def error(folder: Path) -> str:
    with pytest.raises(VlaprobeError) as info:
        check_assets(folder)
    message = str(info.value)
    assert "\n" not in message and "VLAPROBE_LIBERO_ASSETS" in message
    return message


def test_a_whole_folder_passes(assets: Path) -> None:
    check_assets(assets)


@pytest.mark.skipif(not REAL_ASSETS, reason="needs LIBERO's assets (VLAPROBE_LIBERO_ASSETS)")
def test_libero_assets_pass() -> None:
    check_assets(Path(str(REAL_ASSETS)).resolve())


def test_missing_texture(assets: Path) -> None:
    (assets / "articulated_objects/parts/t1.png").unlink()
    message = error(assets)
    assert (
        "articulated_objects/parts/t1.png (used by articulated_objects/wooden_cabinet.xml) is missing"
        in message
    )


def test_styled_floor_texture_is_the_one_checked(assets: Path) -> None:
    (assets / "textures/light-gray-floor-tile.png").unlink()
    assert "textures/light-gray-floor-tile.png (used by scenes/" in error(assets)


def test_truncated_mesh(assets: Path) -> None:
    mesh = assets / "stable_scanned_objects/plate/parts/m4.msh"
    mesh.write_bytes(mesh.read_bytes()[:-7])
    assert "parts/m4.msh (used by stable_scanned_objects/plate/plate.xml) is cut short or damaged" in error(
        assets
    )


def test_truncated_stl_and_png(assets: Path) -> None:
    wall = assets / "scenes/parts/wall.stl"
    wall.write_bytes(wall.read_bytes()[:100])
    assert "scenes/parts/wall.stl" in error(assets)
    wall.write_bytes(stl())
    png = assets / "stable_hope_objects/cookies/parts/t5.png"
    png.write_bytes(PNG[:-5])
    assert "cookies/parts/t5.png (used by stable_hope_objects/cookies/cookies.xml) is cut short" in error(
        assets
    )


def test_empty_mesh_and_malformed_xml(assets: Path) -> None:
    (assets / "articulated_objects/parts/m2.msh").write_bytes(b"")
    assert "parts/m2.msh (used by articulated_objects/flat_stove.xml) is empty" in error(assets)
    (assets / "articulated_objects/parts/m2.msh").write_bytes(msh())
    bowl = assets / SPATIAL_XML_FILES[3]
    bowl.write_text(bowl.read_text().replace("</asset>", ""))
    assert f"{SPATIAL_XML_FILES[3]} is not valid XML (mismatched tag: line 1" in error(assets)
    bowl.unlink()
    assert f"{SPATIAL_XML_FILES[3]} is missing" in error(assets)


def test_assets_folder_errors_are_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("VLAPROBE_LIBERO_ASSETS", "")
    with pytest.raises(VlaprobeError, match="VLAPROBE_LIBERO_ASSETS is empty"):
        prepare_libero()
    assert capsys.readouterr() == ("", "")  # no download chatter
    (tmp_path / "file").write_text("x")
    with pytest.raises(VlaprobeError, match="is a file, not a folder"):
        resolve_assets(tmp_path / "file")
    with pytest.raises(VlaprobeError, match="not found"):
        resolve_assets(tmp_path / "nowhere")
    with pytest.raises(VlaprobeError, match="is missing"):
        resolve_assets(tmp_path)  # a folder, but not LIBERO's assets


def test_listing_tasks_needs_no_assets(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("VLAPROBE_LIBERO_ASSETS", str(tmp_path / "nowhere"))
    assert tasks(TasksConfig()) == 0
    rows = capsys.readouterr().out.splitlines()
    assert len(rows) == 10 and rows[0].startswith(" 0  pick up the black bowl")


# ----- every suite (issue #35) ----------------------------------------------------------------------------
needs_assets = pytest.mark.skipif(not REAL_ASSETS, reason="needs LIBERO's assets (VLAPROBE_LIBERO_ASSETS)")


def test_spatial_files_are_what_its_bddl_files_name() -> None:
    from vlaprobe.envs.suite_assets import asset_files, suite_asset_files

    derived = suite_asset_files("libero_spatial")
    assert set(derived.xml) == set(SPATIAL_XML_FILES) and derived.xml[0] == SPATIAL_XML_FILES[0]
    assert derived.styled == SPATIAL_ASSETS.styled
    assert asset_files("libero_spatial") is SPATIAL_ASSETS
    kitchen = suite_asset_files("libero_10").styled["scenes/libero_kitchen_tabletop_base_style.xml"]
    assert kitchen == {"texplane": "gray_ceramic_tile.png", "tex-wall": "yellow_linen_wall_texture.png"}


@needs_assets
@pytest.mark.parametrize("suite", SUITES)
def test_every_suite_loads_from_the_shared_assets(suite: str) -> None:
    from vlaprobe.envs.suite_assets import asset_files

    check_assets(Path(str(REAL_ASSETS)).resolve(), asset_files(suite), suite)  # type: ignore[arg-type]


def linked_copy(tmp_path: Path) -> Path:
    """The real assets folder as a tree of links to its files (folders real, so a file can be taken away)."""
    real = Path(str(REAL_ASSETS)).resolve()
    copy = tmp_path / "assets"
    for path in real.rglob("*"):
        if path.is_file():
            target = copy / path.relative_to(real)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.symlink_to(path)
    return copy


@needs_assets
def test_a_suite_missing_a_file_is_refused_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vlaprobe.cli import main
    from vlaprobe.envs.suite_assets import asset_files

    copy = linked_copy(tmp_path)
    (copy / "stable_scanned_objects/basket/basket.xml").unlink()
    check_assets(copy, asset_files("libero_spatial"))  # LIBERO-spatial has no basket: its files are whole
    with pytest.raises(VlaprobeError) as info:
        check_assets(copy, asset_files("libero_object"), "libero_object")
    message = str(info.value)
    assert "\n" not in message and message.startswith(
        f"LIBERO assets folder {copy} is missing a file of libero_object"
    )
    assert "stable_scanned_objects/basket/basket.xml is missing" in message
    # before any work: `vlaprobe atoms` refuses in one line, no simulator built
    assert main(["atoms", "--suite", "libero_object", "--env.assets", str(copy)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "stable_scanned_objects/basket/basket.xml is missing" in err


@needs_assets
def test_a_missing_mesh_names_the_xml_that_uses_it(tmp_path: Path) -> None:
    from vlaprobe.envs.suite_assets import asset_files

    copy = linked_copy(tmp_path)
    microwave = copy / "articulated_objects/microwave.xml"
    mesh = referenced_files(microwave)[0]
    mesh.unlink()
    with pytest.raises(
        VlaprobeError,
        match=r"is missing a file of libero_10: .* \(used by articulated_objects/microwave.xml\) is missing",
    ):
        check_assets(copy, asset_files("libero_10"), "libero_10")
    check_assets(copy, asset_files("libero_goal"), "libero_goal")  # no microwave there
