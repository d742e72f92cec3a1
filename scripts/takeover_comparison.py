"""The takeover comparison (docs/failures.md): success without intervention, with the alarm's takeovers and with
as many takeovers at random rows, on the same init states and seeds.

Each ROUND folder holds three stores collected with the same command but for ``--takeover``: ``none/``,
``alarm/`` (``--takeover alarm``) and ``random/`` (``--takeover random --takeover-match ROUND/alarm``). Only the
(task, init) pairs present in all three count (a round still running adds its finished pairs). Prints a
Markdown table (success with its 95% Wilson interval, takeovers and expert actions per episode) and a JSON line.

    python scripts/takeover_comparison.py runs/tko/r40 runs/tko/r41
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from placement_checks import wilson  # the bench's 95% Wilson interval (one copy)

CONDITIONS = ("none", "alarm", "random")


def episodes(store: Path) -> dict[tuple[int, int], tuple[bool, int, int]]:
    """(task, init) -> (success, takeovers, expert actions) of every episode of a store."""
    from vlaprobe.collection.store import ActivationStore

    s = ActivationStore.open(store)
    out = {}
    for info in s.episodes():
        taken = s.episode(info.key).attributes.takeovers
        n, steps = (0, 0) if taken is None else (len(taken.items), taken.expert_steps)
        out[(info.task, info.init)] = (bool(info.success), n, steps)
    return out


def compare(rounds: list[Path]) -> dict[str, dict[str, object]]:
    rows: dict[str, list[tuple[bool, int, int]]] = {c: [] for c in CONDITIONS}
    for r in rounds:
        got = {c: episodes(r / c) for c in CONDITIONS if (r / c / "zarr.json").is_file()}
        if set(got) != set(CONDITIONS):
            continue
        for pair in sorted(set.intersection(*(set(g) for g in got.values()))):
            for c in CONDITIONS:
                rows[c].append(got[c][pair])
    out: dict[str, dict[str, object]] = {}
    for c, eps in rows.items():
        n, k = len(eps), sum(s for s, _, _ in eps)
        low, high = wilson(k, n) if n else (0.0, 1.0)
        low, high = max(0.0, low), min(1.0, high)  # -0.0 at k = 0
        out[c] = {
            "episodes": n,
            "successes": k,
            "rate": k / n if n else None,
            "rate_95": [round(low, 3), round(high, 3)],
            "takeovers_per_episode": sum(t for _, t, _ in eps) / n if n else None,
            "expert_steps_per_episode": sum(e for _, _, e in eps) / n if n else None,
        }
    return out


def main() -> None:
    if len(sys.argv) < 2:
        sys.exit("usage: python scripts/takeover_comparison.py ROUND [ROUND ...]")
    out = compare([Path(a) for a in sys.argv[1:]])
    print(
        "| condition | episodes | successes | success (95% Wilson) | takeovers / episode | expert actions / episode |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for c, r in out.items():
        if not r["episodes"]:
            continue
        low, high = r["rate_95"]  # type: ignore[misc]
        print(
            f"| {c} | {r['episodes']} | {r['successes']} | {100 * r['rate']:.0f}% ({100 * low:.0f}-{100 * high:.0f}%) "  # type: ignore[operator]
            f"| {r['takeovers_per_episode']:.2f} | {r['expert_steps_per_episode']:.1f} |"
        )
    print(json.dumps(out))


if __name__ == "__main__":
    main()
