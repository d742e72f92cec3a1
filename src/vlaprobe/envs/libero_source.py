"""Facts read from the installed libero package's own files, without importing it (no robosuite, no assets).

- :func:`object_facts`: every registered object category's asset XML and its articulation rules (``is_open``,
  ``is_close``, ``turn_on``, ``turn_off``), parsed from the source of ``libero/libero/envs/objects`` with
  :mod:`ast`: each rule is ``qpos <op> min|max(self.object_properties["articulation"][<ranges>])`` there, with
  the ranges assigned in ``__init__``.
- :func:`problem_facts`: each problem class's workspace fixture (skipped when fixtures are built), scene XML and
  floor/wall styles, read from ``libero/libero/envs/problems``.
- :func:`bddl_path`: a task's BDDL file.

Reading the source keeps these numbers LIBERO's own: a LIBERO release that changes a threshold changes ours.
"""

from __future__ import annotations

import ast
import importlib.util
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols import Articulation

OBJECT_MODULES = ("google_scanned_objects", "hope_objects", "turbosquid_objects", "articulated_objects")
RULES = ("is_open", "is_close", "turn_on", "turn_off")


@dataclass(frozen=True)
class ObjectFacts:
    """One registered LIBERO object category: its XML (relative to the assets folder) and joint rules."""

    category: str
    xml: str
    is_open: Articulation | None = None
    is_close: Articulation | None = None
    turn_on: Articulation | None = None
    turn_off: Articulation | None = None


@dataclass(frozen=True)
class ProblemFacts:
    """One LIBERO problem class (the BDDL ``(problem ...)``): what its scene is built from."""

    name: str
    workspace: str
    """Fixture category that is the workspace itself (``table``, ``kitchen_table``, ``floor``...), not an object."""
    scene_xml: str
    floor_style: str
    wall_style: str


def libero_root() -> Path:
    """``site-packages/libero/libero`` of the installed package (found, not imported)."""
    spec = importlib.util.find_spec("libero")
    if spec is None or not spec.submodule_search_locations:
        raise VlaprobeError("LIBERO is not installed; run `bash scripts/setup.sh` (or `make setup`) first")
    return Path(next(iter(spec.submodule_search_locations))) / "libero"


def bddl_path(problem_folder: str, bddl_file: str) -> Path:
    """A task's BDDL file inside the installed package."""
    return libero_root() / "bddl_files" / problem_folder / bddl_file


def category_key(class_name: str) -> str:
    """LIBERO's registry key of a class (``register_object``): ``WoodenCabinet`` -> ``wooden_cabinet``."""
    return "_".join(re.sub(r"([A-Z0-9])", r" \1", class_name).split()).lower()


def _rule(method: ast.FunctionDef, ranges: dict[str, list[float]]) -> Articulation | None:
    """The Articulation a rule method tests: ``qpos <op> min|max(...[key])``."""
    for node in ast.walk(method):
        if not (isinstance(node, ast.Compare) and isinstance(node.left, ast.Name) and node.left.id == "qpos"):
            continue
        call = node.comparators[0]
        if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.args):
            continue
        key = call.args[0]
        if not (isinstance(key, ast.Subscript) and isinstance(key.slice, ast.Constant)):
            continue
        values = ranges.get(str(key.slice.value))
        if not values:
            return None
        threshold = float(min(values) if call.func.id == "min" else max(values))
        op = node.ops[0]
        return Articulation(
            threshold=threshold,
            below=isinstance(op, ast.Lt | ast.LtE),
            strict=isinstance(op, ast.Lt | ast.Gt),
        )
    return None


def _ranges(init: ast.FunctionDef) -> dict[str, list[float]]:
    """``self.object_properties["articulation"][<key>] = [a, b]`` assignments of an ``__init__``."""
    out: dict[str, list[float]] = {}
    for node in ast.walk(init):
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Subscript):
            target = node.targets[0]
            if isinstance(target.slice, ast.Constant) and isinstance(node.value, ast.List):
                out[str(target.slice.value)] = [float(v) for v in ast.literal_eval(node.value)]
    return out


def _obj_name(init: ast.FunctionDef) -> str | None:
    """The default of ``__init__``'s ``obj_name`` argument."""
    args = init.args
    for arg, default in zip(args.args[len(args.args) - len(args.defaults) :], args.defaults, strict=True):
        if arg.arg == "obj_name" and isinstance(default, ast.Constant):
            return str(default.value)
    return None


@lru_cache(maxsize=1)
def object_facts() -> dict[str, ObjectFacts]:
    """Every category registered with ``@register_object`` in LIBERO's object modules."""
    facts: dict[str, ObjectFacts] = {}
    for module in OBJECT_MODULES:
        source = (libero_root() / "envs" / "objects" / f"{module}.py").read_text()
        template = re.search(r'f"(\w+/\{obj_name\}[\w/{}]*\.xml)"', source)
        if template is None:
            raise VlaprobeError(
                f"libero's {module}.py names no asset XML; this LIBERO version is not supported"
            )
        for cls in ast.parse(source).body:
            if not isinstance(cls, ast.ClassDef):
                continue
            if not any(isinstance(d, ast.Name) and d.id == "register_object" for d in cls.decorator_list):
                continue
            methods = {f.name: f for f in cls.body if isinstance(f, ast.FunctionDef)}
            init = methods.get("__init__")
            obj_name = _obj_name(init) if init else None
            ranges = _ranges(init) if init else {}
            rules = {r: _rule(methods[r], ranges) for r in RULES if r in methods}
            key = category_key(cls.name)
            facts[key] = ObjectFacts(
                category=key, xml=template.group(1).replace("{obj_name}", obj_name or key), **rules
            )
    return facts


@lru_cache(maxsize=1)
def problem_facts() -> dict[str, ProblemFacts]:
    """Every problem class of ``libero/libero/envs/problems``, keyed by its lower-case BDDL name."""
    out: dict[str, ProblemFacts] = {}
    for path in sorted((libero_root() / "envs" / "problems").glob("libero_*.py")):
        text = path.read_text()
        found = {
            key: re.search(pattern, text)
            for key, pattern in {
                "name": r"class (\w+)\(",
                "workspace": r'fixture_category == "(\w+)"',
                "scene_xml": r'"scene_xml": "([\w/.-]+)"',
                "floor_style": r'"floor_style": "([\w-]+)"',
                "wall_style": r'"wall_style": "([\w-]+)"',
            }.items()
        }
        if any(m is None for m in found.values()):
            raise VlaprobeError(
                f"cannot read libero's problem class {path.name}; this LIBERO version is not supported"
            )
        values = {k: m.group(1) for k, m in found.items() if m is not None}
        out[values["name"].lower()] = ProblemFacts(**values)
    return out


@lru_cache(maxsize=1)
def texture_styles() -> dict[str, dict[str, str]]:
    """LIBERO's arena styles, ``{"floor": {style: file}, "wall": {style: file}}`` (``envs/arenas/style.py``)."""
    tree = ast.parse((libero_root() / "envs" / "arenas" / "style.py").read_text())
    values = {
        node.targets[0].id: node.value
        for node in tree.body
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name)
    }
    try:
        return {
            "floor": ast.literal_eval(values["FLOOR_STYLE"]),
            "wall": ast.literal_eval(values["WALL_STYLE"]),
        }
    except (KeyError, ValueError):
        raise VlaprobeError(
            "cannot read libero's arena styles; this LIBERO version is not supported"
        ) from None
