"""Layers only point down: a package imports only the packages below it in :data:`ORDER`."""

from __future__ import annotations

import ast
from pathlib import Path

import vlaprobe

ORDER = (
    "errors",
    "files",
    "locks",
    "devices",
    "symbols",
    "configs",
    "envs",
    "experts",
    "policies",
    "rollout",
    "collection",
    "finetune",
    "probes",
    "reports",
    "cognition",
    "live",
    "results",
    "pipeline",
    "doctor",
    "commands",
    "cli",
)
"""Every top-level module or package of ``vlaprobe``, lowest first (the data flow, then the entry points)."""

ROOT = Path(vlaprobe.__file__).parent


def _is_module(name: str) -> bool:
    return (ROOT / name).is_dir() or (ROOT / f"{name}.py").is_file()


def imports(path: Path) -> list[tuple[str, int]]:
    """(imported vlaprobe top-level name, line) of every import in a file, lazy and TYPE_CHECKING ones too."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
            if (
                node.module == "vlaprobe"
            ):  # ``from vlaprobe import live`` names a module; ``__version__`` is none
                names = [f"vlaprobe.{a.name}" for a in node.names if _is_module(a.name)]
        found += [(n.split(".")[1], node.lineno) for n in names if n.startswith("vlaprobe.")]
    return found


def test_every_import_points_down() -> None:
    upward = []
    for path in sorted(ROOT.rglob("*.py")):
        layer = path.relative_to(ROOT).parts[0].removesuffix(".py")
        if layer == "__init__":
            continue
        assert layer in ORDER, f"{layer} has no place in ORDER; add it where it belongs"
        for name, line in imports(path):
            assert name in ORDER, f"{path}:{line} imports vlaprobe.{name}, which has no place in ORDER"
            if ORDER.index(name) > ORDER.index(layer):
                upward.append(f"{path.relative_to(ROOT)}:{line} ({layer}) imports vlaprobe.{name}")
    assert not upward, "lower layers import higher ones:\n" + "\n".join(upward)


def test_the_check_sees_an_upward_import(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from vlaprobe.live.serve import main\n    import vlaprobe.cognition\n")
    assert imports(bad) == [("live", 2), ("cognition", 3)]
