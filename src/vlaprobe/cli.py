"""`vlaprobe <command>`: a thin command line over functions that can be called directly.

Each command (:data:`vlaprobe.commands.COMMANDS`) is a configuration dataclass (declared once in
:mod:`vlaprobe.configs`, shared with the Python API) and the function that runs it. Every command takes
``--config FILE`` (a JSON or YAML file, e.g. a run's ``config.json``): the file gives the defaults, flags
override them. Heavy modules are imported only when the command runs.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import io
import json
import re
import sys
from pathlib import Path
from typing import Annotated, Any, Protocol

import tyro

from vlaprobe.commands import ALIASES, COMMANDS, Command
from vlaprobe.envs.checks import precheck
from vlaprobe.errors import VlaprobeError

CONFIG_HELP = (
    "JSON or YAML file of this command's settings (e.g. a run's config.json, written by every run); "
    "the other flags override its values."
)


def _load_config_file(path: Path, cls: type) -> Any:
    """Build ``cls`` from a JSON or YAML file written by an earlier run (unknown keys are refused)."""
    if not path.is_file():
        what = f"{path} is a folder, not a file" if path.is_dir() else f"not found: {path}"
        raise VlaprobeError(f"config file {what}; pass an existing .json or .yaml file to --config")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise VlaprobeError(
            f"config file {path} is not text (not UTF-8); pass a .json or .yaml file to --config"
        ) from None
    try:
        if path.suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        else:
            data = json.loads(text)
    except Exception as exc:
        reason = " ".join(str(exc).split())  # YAML's errors span several lines (with a pointer): one line
        raise VlaprobeError(
            f"cannot parse config file {path}: {reason}; fix the file or pass another"
        ) from None
    if not isinstance(data, dict):
        raise VlaprobeError(f"config file {path} must hold a mapping of field names to values")
    if cls.__name__ != "RunConfig" and {"collect", "train", "report"} <= set(data):
        raise VlaprobeError(
            f"config file {path} is a whole run's config (vlaprobe run); repeat the run with "
            f"`vlaprobe run --config {path}`, or pass a stage's own config.json (e.g. {path.parent}/probes/config.json)"
        )
    from vlaprobe.configs import config_from_dict

    return config_from_dict(cls, data, source=str(path))


def _config_path(args: list[str]) -> Path | None:
    """The file of ``--config FILE`` or ``--config=FILE`` among ``args``."""
    for i, arg in enumerate(args):
        if arg == "--config":
            if i + 1 >= len(args) or args[i + 1].startswith("--"):
                raise VlaprobeError("--config needs a file path, e.g. --config runs/default/config.json")
            return Path(args[i + 1])
        if arg.startswith("--config="):
            return Path(arg.split("=", 1)[1])
    return None


def _with_config_flag(cls: type, default: Any) -> type:
    """``cls``'s flags (unprefixed) plus ``--config FILE``, with ``default`` as the values."""
    return dataclasses.make_dataclass(
        cls.__name__,
        [
            ("config", Annotated[Path | None, tyro.conf.arg(metavar="FILE", help=CONFIG_HELP)], None),
            (
                "cfg",
                Annotated[cls, tyro.conf.arg(name="")],
                dataclasses.field(default_factory=lambda: default),
            ),
        ],
    )


class _Parsed(Protocol):
    """The parsed flags: ``--config`` and the command's config."""

    cfg: object


def _parse_command(name: str, command: Command, args: list[str]) -> Any:
    cls = command.config_class()
    path = _config_path(args)
    default = _load_config_file(path, cls) if path is not None else cls()
    _check_empty_values(args)
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            parsed: _Parsed = tyro.cli(
                _with_config_flag(cls, default), args=args, prog=f"vlaprobe {name}", description=command.help
            )
    except SystemExit as exc:
        if exc.code in (0, None):
            sys.stderr.write(captured.getvalue())
            raise
        raise VlaprobeError(f"{_one_line(captured.getvalue())}; see `vlaprobe {name} --help`") from None
    sys.stderr.write(captured.getvalue())  # tyro's warnings, if any
    return parsed.cfg


def _one_line(panel: str) -> str:
    """The message of tyro's boxed parse error, without the box, the help text and the pointer to --help."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", panel)
    lines = [line.strip(" │╭╮╰╯") for line in text.splitlines()[1:-1]]
    message = []
    for line in lines:
        if line and set(line) <= {"─"}:
            break
        message.append(line)
    return " ".join(" ".join(message).split()) or "could not parse the command line"


PATH_FLAGS = (
    "out",
    "store",
    "probes",
    "observer-store",
    "observer_store",
    "assets",
    "recordings",
    "model",
    "path",
    "token-file",
    "token_file",
)
"""Flags (last dotted part) whose empty value would silently mean the current folder."""


def _check_empty_values(args: list[str]) -> None:
    """Refuse ``--out ''`` and the like: an empty path is the current folder, never what was meant."""
    for i, arg in enumerate(args):
        flag, eq, value = arg.partition("=")
        if not flag.startswith("--") or flag.rsplit(".", 1)[-1].lstrip("-") not in PATH_FLAGS:
            continue
        if (eq and not value) or (not eq and i + 1 < len(args) and args[i + 1] == ""):
            raise VlaprobeError(f"{flag} got an empty value; give it a path")


def _top_level_help() -> str:
    width = max(len(n) for n in COMMANDS) + 2
    rows = "\n".join(f"  {name:<{width}}{c.help}" for name, c in COMMANDS.items())
    return (
        f"usage: vlaprobe {{{','.join(COMMANDS)}}} [--config FILE] [OPTIONS]\n\n"
        "Probe a vision-language-action model for symbolic world states.\n\n"
        f"commands:\n{rows}\n\n"
        "Every command takes --help and --config FILE (a JSON or YAML file of its settings, e.g. a run's "
        "config.json).\n"
    )


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``vlaprobe`` console script; returns the exit status."""
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        if args and args[0] in ("-h", "--help"):
            print(_top_level_help(), end="")
            return 0
        if not args or args[0].startswith("-"):
            given = f"unknown option {args[0]!r}" if args else "no command given"
            raise VlaprobeError(f"{given}; usage: vlaprobe COMMAND [OPTIONS] (see `vlaprobe --help`)")
        name = args[0]
        if name in ALIASES:
            name = ALIASES[name]
            print(f"vlaprobe: `vlaprobe {args[0]}` is deprecated; use `vlaprobe {name}`", file=sys.stderr)
        if name not in COMMANDS:
            raise VlaprobeError(
                f"unknown command {name!r}; the commands are {', '.join(COMMANDS)} (see `vlaprobe --help`)"
            )
        cfg = _parse_command(name, COMMANDS[name], args[1:])
        precheck(cfg)
        result = COMMANDS[name].function()(cfg)
        return int(result) if isinstance(result, int) and not isinstance(result, bool) else 0
    except VlaprobeError as exc:
        print(f"vlaprobe: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. `vlaprobe atoms --json | head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("vlaprobe: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # a full disk, a read-only or vanished folder met while writing
        where = f" {exc.filename}" if exc.filename else ""
        reason = exc.strerror or str(exc)
        fix = (
            "free some disk space"
            if exc.errno in (errno.ENOSPC, errno.EDQUOT)
            else "check the path and its permissions"
        )
        print(f"vlaprobe: error: cannot access{where}: {reason}; {fix} and rerun", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
