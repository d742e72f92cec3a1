"""Configuration dataclasses, declared once and shared by the CLI and the Python API.

Every field is documented where it is declared (the docstring under it becomes the ``--help`` text). The
commands that take them are listed in :data:`vlaprobe.commands.COMMANDS`. Config files (JSON or YAML, e.g. a
run's ``config.json``) are read with dacite: unknown fields and wrong types are refused in one line.
"""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import dacite

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import Json, JsonObject

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

C = TypeVar("C")


def config_to_dict(cfg: DataclassInstance) -> JsonObject:
    """A JSON-ready dict of a config dataclass (nested dataclasses, paths as strings, tuples as lists)."""
    out: JsonObject = {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            v = config_to_dict(v)
        elif isinstance(v, Path):
            v = str(v)
        elif isinstance(v, tuple):
            v = [str(x) if isinstance(x, Path) else x for x in v]
        out[f.name] = v
    return out


def _int_as_float(value: Json) -> Json:
    return float(value) if isinstance(value, int) and not isinstance(value, bool) else value


def _str_as_path(value: Json) -> Json:
    return Path(value) if isinstance(value, str) else value


_DACITE = dacite.Config(
    strict=True,  # unknown keys are an error, not silently dropped
    cast=[tuple],  # JSON lists -> tuple fields (element types are still checked)
    type_hooks={float: _int_as_float, Path: _str_as_path},
)


def merged_over(default: DataclassInstance, data: JsonObject) -> JsonObject:
    """``data`` merged field by field over ``default``'s values: a section given as a mapping (``collect:``)
    replaces only the fields it names, at any depth; every other value replaces the default's."""
    out = config_to_dict(default)
    for key, value in data.items():
        current = getattr(default, key, None)
        if isinstance(value, dict) and dataclasses.is_dataclass(current) and not isinstance(current, type):
            out[key] = merged_over(current, value)
        else:
            out[key] = value
    return out


def config_from_dict(cls: type[C], data: JsonObject, source: str = "config") -> C:
    """Build a config dataclass from a dict (as written by :func:`config_to_dict`), merged field by field over
    ``cls()``'s own defaults (:func:`merged_over`: a run's ``collect:`` keeps the run's collection defaults);
    unknown keys are refused."""
    try:
        base = cls()
        return dacite.from_dict(cls, merged_over(base, data), config=_DACITE)  # type: ignore[arg-type]
    except dacite.UnexpectedDataError as exc:
        raise VlaprobeError(
            f"{source}: unknown field(s) {sorted(exc.keys)} for {cls.__name__}; remove them"
        ) from None
    except dacite.WrongTypeError as exc:
        raise VlaprobeError(
            f"{source}: field {exc.field_path!r} expects {_type_name(exc.field_type)}, got {exc.value!r}; fix the file"
        ) from None
    except dacite.DaciteError as exc:
        raise VlaprobeError(f"{source}: {exc}; fix the file") from None
    except (TypeError, ValueError) as exc:  # e.g. a number where a list belongs (tuple(5))
        raise VlaprobeError(f"{source}: {exc}; fix the file") from None


def _type_name(tp: object) -> str:
    if typing.get_origin(tp) is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")
