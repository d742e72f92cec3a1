"""Publish a run's headline figures into docs/results/, the file the README and docs quote.

    .venv/bin/python scripts/publish_results.py runs/default            # → docs/results/default.json
    .venv/bin/python scripts/publish_results.py runs/diverse --name diverse

Reads ``<run>/results.json`` (written by ``vlaprobe run``) through its reader, which validates it; a run
written before that file existed is read from its ``probes/evaluation.json`` and ``probes/monitor.json``
instead. Writes ``docs/results/<name>.json`` with the one writer and prints every figure that changed since
the published copy. Then ``pytest tests/test_docs_figures.py`` names each quoted figure that now disagrees.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vlaprobe.errors import VlaprobeError
from vlaprobe.results import RESULTS_FILE, RunResults, read_results, results_from_run, write_results

DOCS_RESULTS = Path(__file__).resolve().parent.parent / "docs" / "results"


def changes(old: RunResults | None, new: RunResults) -> list[str]:
    """One line per figure that differs between two results (added, removed or changed)."""
    before = {} if old is None else old.figures
    keys = sorted(set(before) | set(new.figures))
    return [
        f"{k}: {before.get(k, '(none)')} → {new.figures.get(k, '(none)')}"
        for k in keys
        if before.get(k, "(none)") != new.figures.get(k, "(none)")
    ]


def publish(run: Path, name: str, docs: Path = DOCS_RESULTS) -> tuple[Path, list[str]]:
    """Copy ``run``'s results into ``docs/<name>.json``; return the path and the figures that changed."""
    if not run.is_dir():
        raise VlaprobeError(f"{run} is not a folder; pass a run folder written by vlaprobe run")
    results = read_results(run) if (run / RESULTS_FILE).is_file() else results_from_run(run)
    target = docs / f"{name}.json"
    old = read_results(target) if target.is_file() else None
    return write_results(docs, results, name=f"{name}.json"), changes(old, results)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run", type=Path, help="a run folder written by vlaprobe run")
    parser.add_argument("--name", help="the published file's name (default: the run folder's name)")
    parser.add_argument("--docs", type=Path, default=DOCS_RESULTS, help="where the published files live")
    args = parser.parse_args(argv)
    try:
        path, changed = publish(args.run, args.name or args.run.resolve().name, args.docs)
    except VlaprobeError as exc:
        print(f"publish_results: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}; {len(changed)} figures changed")
    for line in changed:
        print(f"  {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
