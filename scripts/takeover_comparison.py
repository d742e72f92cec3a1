"""The takeover comparison (docs/failures.md): success without intervention, with the alarm's takeovers and with
as many takeovers at random rows, on the same init states and seeds.

Each ROUND folder holds three stores collected with the same command but for ``--takeover``: ``none/``,
``alarm/`` (``--takeover alarm``) and ``random/`` (``--takeover random --takeover-match ROUND/alarm``). Only the
(task, init) pairs present in all three count (a round still running adds its finished pairs). Prints a
Markdown table (success with its 95% Wilson interval, takeovers and expert actions per episode, how the
takeovers ended) and a JSON line. A round's ``none/`` does not depend on the takeover settings: the same store
serves every takeover variant collected with the same tasks, init states, seeds and ``--env.max-steps``.

    python scripts/takeover_comparison.py runs/tko2/r40 runs/tko2/r41
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from placement_checks import wilson  # the bench's 95% Wilson interval (one copy)

CONDITIONS = ("none", "alarm", "random")


Episode = tuple[bool, int, int, tuple[str, ...]]
"""(success, takeovers, expert actions, how each takeover ended)."""


def ending(ended: str) -> str:
    """A takeover's end in one word: "subgoal", "goal", "cap", "steps", or "episode end" ("")."""
    return ended.split(":")[0] if ended else "episode end"


def episodes(store: Path) -> dict[tuple[int, int], Episode]:
    """(task, init) -> :data:`Episode` of every episode of a store."""
    from vlaprobe.collection.store import ActivationStore

    s = ActivationStore.open(store)
    out = {}
    for info in s.episodes():
        taken = s.episode(info.key).attributes.takeovers
        items = [] if taken is None else taken.items
        steps = 0 if taken is None else taken.expert_steps
        out[(info.task, info.init)] = (
            bool(info.success),
            len(items),
            steps,
            tuple(ending(t.ended) for t in items),
        )
    return out


def compare(rounds: list[Path]) -> dict[str, dict[str, object]]:
    rows: dict[str, list[Episode]] = {c: [] for c in CONDITIONS}
    for r in rounds:
        got = {c: episodes(r / c) for c in CONDITIONS if (r / c / "zarr.json").is_file()}
        if set(got) != set(CONDITIONS):
            continue
        for pair in sorted(set.intersection(*(set(g) for g in got.values()))):
            for c in CONDITIONS:
                rows[c].append(got[c][pair])
    out: dict[str, dict[str, object]] = {}
    for c, eps in rows.items():
        n, k = len(eps), sum(e[0] for e in eps)
        taken = sum(e[1] for e in eps)
        low, high = wilson(k, n) if n else (0.0, 1.0)
        low, high = max(0.0, low), min(1.0, high)  # -0.0 at k = 0
        out[c] = {
            "episodes": n,
            "successes": k,
            "rate": k / n if n else None,
            "rate_95": [round(low, 3), round(high, 3)],
            "takeovers_per_episode": taken / n if n else None,
            "expert_steps_per_episode": sum(e[2] for e in eps) / n if n else None,
            "actions_per_takeover": sum(e[2] for e in eps) / taken if taken else None,
            "ended": dict(sorted(Counter(x for e in eps for x in e[3]).items())),
        }
    return out


def main() -> None:
    if len(sys.argv) < 2:
        sys.exit("usage: python scripts/takeover_comparison.py ROUND [ROUND ...]")
    out = compare([Path(a) for a in sys.argv[1:]])
    print(
        "| condition | episodes | successes | success (95% Wilson) | takeovers / episode | expert actions / episode "
        "| actions / takeover | takeovers ended by |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for c, r in out.items():
        if not r["episodes"]:
            continue
        low, high = r["rate_95"]  # type: ignore[misc]
        per = r["actions_per_takeover"]
        ends = ", ".join(f"{k} {v}" for k, v in r["ended"].items()) or "-"  # type: ignore[attr-defined]
        print(
            f"| {c} | {r['episodes']} | {r['successes']} | {100 * r['rate']:.0f}% ({100 * low:.0f}-{100 * high:.0f}%) "  # type: ignore[operator]
            f"| {r['takeovers_per_episode']:.2f} | {r['expert_steps_per_episode']:.1f} "
            f"| {'-' if per is None else f'{per:.1f}'} | {ends} |"
        )
    print(json.dumps(out))


if __name__ == "__main__":
    main()
