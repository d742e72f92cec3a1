"""Bounds on users' rules files: checked before use, bounded while used (:class:`~vlaprobe.configs.monitor.RuleBudget`).

clingo 5 cannot interrupt its grounder, so a program with a user's file is first grounded in a child process
(:mod:`.ground_child`) under a time, memory and size budget; only a program that grounds within it is grounded
in this process. Solving can be interrupted: each step's solve runs asynchronously and is cancelled at the
budget, or at once when the process shuts down (:func:`interrupt_solves`). An error names the rule to blame:
for grounding, a recursive rule that builds new terms (``n(X+1) :- n(X).``: the only way a program over a
finite vocabulary grounds without end); for solving, a rule that makes choices.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import clingo
import clingo.ast

from vlaprobe.configs.monitor import RuleBudget
from vlaprobe.errors import VlaprobeError

STARTUP_SECONDS = 60.0
"""Time the child may take to start (Python and clingo) before its grounding budget starts."""
_CHECKED: set[str] = set()
"""Programs (hash of text, files and budget) already grounded within their budget in a child."""
_ACTIVE: set[clingo.Control] = set()
"""Controls solving users' rules now (what :func:`interrupt_solves` interrupts)."""
_LOCK = threading.Lock()


def read_rules_text(path: Path) -> str:
    """A rules file's text, or one line if it cannot be read or is not UTF-8 (clingo would fail inside)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise VlaprobeError(
            f"cannot read rules file {path} ({exc.strerror}); pass a readable .lp file"
        ) from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise VlaprobeError(
            f"rules file {path} is not UTF-8 text (byte {exc.start}); save it as UTF-8 (ASP text)"
        ) from None


def check_budget(budget: RuleBudget) -> None:
    """Refuse a budget that bounds nothing or everything."""
    for name in ("ground_seconds", "solve_seconds"):
        value = getattr(budget, name)
        if not value > 0:
            raise VlaprobeError(f"rule budget {name} must be > 0 seconds, got {value}")
    for name in ("ground_atoms", "ground_memory_mb"):
        if getattr(budget, name) < 1:
            raise VlaprobeError(f"rule budget {name} must be >= 1, got {getattr(budget, name)}")


def _statements(files: Iterable[Path]) -> list[tuple[Path, clingo.ast.AST]]:
    out: list[tuple[Path, clingo.ast.AST]] = []
    for path in files:
        with contextlib.suppress(RuntimeError):  # syntax errors are reported by the real load
            clingo.ast.parse_files(
                [str(path)],
                lambda s, p=path: out.append((p, s)),  # type: ignore[misc]
                logger=lambda code, msg: None,
            )
    return out


def _children(node: clingo.ast.AST) -> list[clingo.ast.AST]:
    out = []
    for key in node.child_keys:
        child = getattr(node, key)
        out += [child] if isinstance(child, clingo.ast.AST) else [c for c in child or () if c is not None]
    return out


def _signatures(node: clingo.ast.AST, out: set[str]) -> None:
    """Predicate names of the symbolic atoms under ``node``."""
    if (
        node.ast_type == clingo.ast.ASTType.SymbolicAtom
        and node.symbol.ast_type == clingo.ast.ASTType.Function
    ):
        out.add(node.symbol.name)
    for c in _children(node):
        _signatures(c, out)


def _builds_terms(node: clingo.ast.AST) -> bool:
    """Whether ``node`` holds arithmetic or a function term with arguments inside an atom's arguments."""
    kinds = (
        clingo.ast.ASTType.BinaryOperation,
        clingo.ast.ASTType.UnaryOperation,
        clingo.ast.ASTType.Interval,
    )
    if node.ast_type in kinds:
        return True
    function = clingo.ast.ASTType.Function
    return any(
        (c.ast_type == function and node.ast_type == function and len(c.arguments) > 0) or _builds_terms(c)
        for c in _children(node)
    )


def _where(path: Path, stmt: clingo.ast.AST) -> str:
    return f"{path}:{stmt.location.begin.line}: `{' '.join(str(stmt).split())}`"


def growing_rules(files: Sequence[Path]) -> list[str]:
    """Rules (``file:line: `rule```) that derive a predicate from itself while building new terms."""
    rules = []
    for path, s in _statements(files):
        if s.ast_type == clingo.ast.ASTType.Rule:
            heads: set[str] = set()
            body: set[str] = set()
            _signatures(s.head, heads)
            for lit in s.body:
                _signatures(lit, body)
            rules.append((path, s, heads, body))
    edges: dict[str, set[str]] = {}  # head -> the predicates it is derived from
    for _, _, heads, body in rules:
        for h in heads:
            edges.setdefault(h, set()).update(body)

    def reaches(start: set[str], goal: set[str]) -> bool:
        seen: set[str] = set()
        todo = list(start)
        while todo:
            p = todo.pop()
            if p in goal:
                return True
            if p not in seen:
                seen.add(p)
                todo.extend(edges.get(p, ()))
        return False

    return [
        _where(path, s)
        for path, s, heads, body in rules
        if heads and _builds_terms(s.head) and reaches(body, heads)
    ]


def choice_rules(files: Sequence[Path]) -> list[str]:
    """Rules whose head chooses (a choice, an aggregate or a disjunction): where the search can blow up."""
    kinds = (clingo.ast.ASTType.Aggregate, clingo.ast.ASTType.HeadAggregate, clingo.ast.ASTType.Disjunction)
    return [
        _where(p, s)
        for p, s in _statements(files)
        if s.ast_type == clingo.ast.ASTType.Rule and s.head.ast_type in kinds
    ]


def _blame(rules: list[str], files: Sequence[Path], does: str) -> str:
    """ "rule FILE:LINE: `...` <does>", or the files when no single rule is to blame."""
    if rules:
        return f"rule {rules[0]} {does}"
    return "one of the rules of " + ", ".join(str(p) for p in files) + f" {does}"


def check_grounding(program: str, files: Sequence[Path], users: Sequence[Path], budget: RuleBudget) -> None:
    """Ground ``program`` plus ``files`` in a child process within ``budget``; one line naming the rule to
    blame if it runs out of time, memory or atoms. ``users``: the user's files among ``files``."""
    key = hashlib.sha256(
        json.dumps([program, [p.read_bytes().hex() for p in files], repr(budget)]).encode()
    ).hexdigest()
    if key in _CHECKED:
        return
    request = {
        "programs": [program],
        "files": [str(p) for p in files],
        "memory_bytes": budget.ground_memory_mb << 20,
        "seconds": budget.ground_seconds,
    }
    child = [sys.executable, "-I", str(Path(__file__).with_name("ground_child.py"))]
    try:
        done = subprocess.run(
            child,
            input=json.dumps(request) + "\n",
            capture_output=True,
            text=True,
            timeout=STARTUP_SECONDS + budget.ground_seconds,
        )
        lines = done.stdout.splitlines()
        answer: dict[str, Any] = {"status": "killed", "code": done.returncode}
        if len(lines) > 1:
            answer = json.loads(lines[1])
    except subprocess.TimeoutExpired as exc:  # its output: bytes whatever ``text`` says
        out = exc.stdout or b""
        lines = (out.decode() if isinstance(out, bytes) else out).splitlines()
        answer = {"status": "killed", "code": None}
    if not lines:
        raise VlaprobeError(
            f"the process that grounds the rules could not start within {budget.ground_memory_mb} MB of memory "
            f"and {STARTUP_SECONDS:g} s; raise the rule budget's ground_memory_mb"
        )
    status = answer["status"]
    blame = _blame(growing_rules(users), users, "builds new terms without end")
    if status in ("killed", "memory"):
        timer = status == "killed" and answer["code"] in (None, -14)  # -14: SIGALRM, its timer
        what, knob = (
            (f"did not finish within {budget.ground_seconds:g} s", "ground_seconds")
            if timer
            else (f"ran out of its {budget.ground_memory_mb} MB of memory", "ground_memory_mb")
        )
        raise VlaprobeError(
            f"grounding the rules {what}: {blame}; make it finite (or raise the rule budget's {knob})"
        )
    if status == "ok" and answer["atoms"] > budget.ground_atoms:
        raise VlaprobeError(
            f"grounding the rules gave {answer['atoms']} atoms, over the budget of {budget.ground_atoms}: "
            f"{blame}; make it smaller (or raise the rule budget's ground_atoms)"
        )
    if status == "ok":
        _CHECKED.add(key)


def interrupt_solves() -> None:
    """Interrupt every solve of users' rules running now (the process is shutting down): each ends with one
    line instead of running on to its budget."""
    with _LOCK:
        for ctl in _ACTIVE:
            ctl.interrupt()


def solve_within(
    ctl: clingo.Control,
    on_model: Callable[[clingo.Model], bool | None],
    seconds: float,
    users: Sequence[Path],
) -> clingo.SolveResult:
    """``ctl.solve`` cancelled after ``seconds`` (one line naming a choosing rule) or by :func:`interrupt_solves`."""
    deadline = time.monotonic() + seconds
    with _LOCK:
        _ACTIVE.add(ctl)
    try:
        solving = ctl.solve(on_model=on_model, async_=True)
        assert isinstance(solving, clingo.SolveHandle)
        with solving as handle:
            while not handle.wait(0.05):  # short waits: the GIL is free for the server between them
                if time.monotonic() >= deadline:
                    handle.cancel()
                    raise VlaprobeError(
                        f"solving the rules took longer than {seconds:g} s: "
                        f"{_blame(choice_rules(users), users, 'makes the search too hard')}; simplify it "
                        "(or raise the rule budget's solve_seconds)"
                    )
            result: clingo.SolveResult = handle.get()
    finally:
        with _LOCK:
            _ACTIVE.discard(ctl)
    if result.interrupted:
        raise VlaprobeError("the rules' solve was interrupted: the server is shutting down")
    return result
