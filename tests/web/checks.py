"""What the end-to-end test checks on the page, each against the server's own record of the episode.

The scenario (browser.py) calls these; each takes the Playwright page and the record from GET /api/episodes/{id}.
"""

from __future__ import annotations

import base64
import json
import urllib.request
from pathlib import Path
from typing import Any

FADE_STEPS = 5
"""web/src/lib/flips.ts DEFAULT_FADE_STEPS: steps an atom stays marked as just flipped."""
AXE = Path(__file__).resolve().parents[2] / "web" / "node_modules" / "axe-core" / "axe.min.js"
"""axe-core (a devDependency of web/, installed by `npm ci`), injected into the page for the contrast check."""


def get_json(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=30) as res:
        return json.loads(res.read())


def get_bytes(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=30) as res:
        return res.read()


def expected_states(predicted: list[list[int]], k: int) -> list[str]:
    """The belief panel's state of every atom at step k: turned-on/-off within FADE_STEPS of a flip, else on/off."""
    out = []
    for i, v in enumerate(predicted[k]):
        flipped = any(predicted[j][i] != predicted[j + 1][i] for j in range(max(0, k - FADE_STEPS), k))
        out.append(("turned-on" if v else "turned-off") if flipped else ("on" if v else "off"))
    return out


def bits(step: dict, key: str) -> list[int] | None:
    if key == "predicted":
        return step["predicted"]["object"]["values"] + step["predicted"]["action"]["values"]
    t = step["truth"]
    return None if t is None else t["object"] + t["action"]


def atom_names(record: dict) -> list[str]:
    return record["start"]["atoms"]["object"] + record["start"]["atoms"]["action"]


def pinned_names(record: dict) -> set[str]:
    """The task-relevant atoms: every action atom and the atoms that mention a goal object."""
    objects = set(record["start"]["goal_objects"])
    assert objects, "episode_start names no goal objects"
    out = set(record["start"]["atoms"]["action"])
    for name in record["start"]["atoms"]["object"]:
        args = name[name.index("(") + 1 : -1].split(",")
        if objects & set(args):
            out.add(name)
    return out


def differing(record: dict, k: int) -> set[str]:
    """The probed atoms whose prediction differs from the world at step k."""
    step = record["steps"][k]
    probed = record["start"]["probed"]["object"] + record["start"]["probed"]["action"]
    pairs = zip(
        atom_names(record), bits(step, "predicted") or [], bits(step, "truth") or [], probed, strict=True
    )
    return {name for name, p, w, ok in pairs if ok and p != w}


def shown_state(page: Any) -> dict[str, Any]:
    return page.evaluate(
        """() => ({
          index: Number(document.querySelector('[data-testid=step-indicator]').dataset.index),
          t: Number(document.querySelector('[data-testid=step-indicator]').dataset.t),
          following: document.querySelector('[data-testid=step-indicator]').dataset.following === '1',
          src: document.querySelector('[data-testid=camera]')?.getAttribute('src') ?? null,
          agreement: document.querySelector('[data-testid=agreement]').textContent,
          atoms: [...document.querySelectorAll('[data-testid=atom]')].map(
            (e) => [e.dataset.atom, e.dataset.state, e.dataset.agree, e.dataset.pinned]),
          pinned: [...document.querySelectorAll('[data-testid=pinned] [data-testid=atom]')].map((e) => e.dataset.atom),
          violations: [...document.querySelectorAll('[data-testid=violations] [data-rule]')].map(
            (e) => e.dataset.rule),
        })"""
    )


def check_frame(base: str, frame_id: str, shown: dict, t: int) -> None:
    """The image shown is the server's frame t of the episode (byte for byte when it came over the socket)."""
    src = shown["src"]
    assert src, f"no image shown at step {t}"
    if src.startswith("data:image/jpeg;base64,"):
        frame = get_bytes(f"{base}/api/episodes/{frame_id}/frames/{t}")
        assert base64.b64decode(src.split(",", 1)[1]) == frame, f"image at step {t} differs from the server's"
    else:
        assert src.split("?")[0].endswith(f"/api/episodes/{frame_id}/frames/{t}"), src


def check_step(page: Any, base: str, record: dict, k: int) -> None:
    """The image, every atom's state and agreement, the agreement % and the violations of recorded step k.

    Needs every atom on the page: the beliefs' filter on "all" with the unprobed atoms shown.
    """
    shown = shown_state(page)
    steps = record["steps"]
    step = steps[k]
    assert shown["index"] == k and shown["t"] == step["t"], (shown["index"], shown["t"], k)
    check_frame(base, record["start"].get("store_episode") or record["start"]["episode_id"], shown, step["t"])
    names = atom_names(record)
    predicted = [bits(s, "predicted") for s in steps]
    states = expected_states(predicted, k)  # type: ignore[arg-type]
    got = {a: (s, agree) for a, s, agree, _ in shown["atoms"]}
    assert set(got) == set(names), set(names) ^ set(got)
    truth = bits(step, "truth")
    probed = record["start"]["probed"]["object"] + record["start"]["probed"]["action"]
    for i, name in enumerate(names):
        assert got[name][0] == states[i], (name, got[name], states[i], k)
        if truth is not None and probed[i]:
            assert got[name][1] == ("agree" if predicted[k][i] == truth[i] else "disagree"), name  # type: ignore[index]
        else:
            assert got[name][1] == "unknown", name
    if truth is not None:
        pairs = [(p, w) for p, w, ok in zip(predicted[k], truth, probed, strict=True) if ok]  # type: ignore[arg-type]
        percent = 100 * sum(p == w for p, w in pairs) / len(pairs)
        assert f"agreement {percent:.1f} %" in shown["agreement"], shown["agreement"]
    assert shown["violations"] == [v["rule"] for v in step["violations"]]


def check_focused_view(page: Any, record: dict, k: int) -> dict[str, int]:
    """At step k (shown): the pinned rows are the task-relevant atoms, and with the disagreement filter the page
    shows exactly the atoms that differ from the world, the task-relevant ones pinned on top."""
    page.check("[data-testid=filter-all]")
    page.uncheck("[data-testid=show-unprobed]")
    probed = dict(
        zip(
            atom_names(record),
            record["start"]["probed"]["object"] + record["start"]["probed"]["action"],
            strict=True,
        )
    )
    pinned = pinned_names(record)
    shown = shown_state(page)
    assert set(shown["pinned"]) == {a for a in pinned if probed[a]}, set(shown["pinned"]) ^ pinned
    assert {a for a, *_ in shown["atoms"]} == {a for a, ok in probed.items() if ok}  # unprobed hidden
    page.check("[data-testid=filter-disagree]")
    shown = shown_state(page)
    wrong = differing(record, k)
    assert {a for a, *_ in shown["atoms"]} == wrong, {a for a, *_ in shown["atoms"]} ^ wrong
    assert set(shown["pinned"]) == wrong & pinned, set(shown["pinned"]) ^ (wrong & pinned)
    assert all(agree == "disagree" for _, _, agree, _ in shown["atoms"])
    n_pinned = len(shown["pinned"])  # pinned first in page order
    assert [a for a, *_ in shown["atoms"]][:n_pinned] == shown["pinned"]
    page.check("[data-testid=filter-changed]")  # predicted or world changed within the fade window
    names = atom_names(record)
    pred = [bits(s, "predicted") or [] for s in record["steps"]]
    world = [bits(s, "truth") or [] for s in record["steps"]]
    lo = max(0, k - FADE_STEPS)
    changed = {
        names[i]
        for i in range(len(names))
        if probed[names[i]]
        and any(pred[j][i] != pred[j + 1][i] or world[j][i] != world[j + 1][i] for j in range(lo, k))
    }
    got = {a for a, *_ in shown_state(page)["atoms"]}
    assert got == changed, got ^ changed
    page.check("[data-testid=show-unprobed]")
    page.check("[data-testid=filter-all]")
    return {"pinned": len(pinned), "differing": len(wrong), "differing_pinned": len(wrong & pinned)}


def contrast_violations(page: Any) -> list[dict]:
    """axe-core's color-contrast rule on the whole page: the offending elements (an empty list passes)."""
    if not page.evaluate("() => typeof window.axe !== 'undefined'"):
        page.add_script_tag(path=str(AXE))
    result = page.evaluate(
        """async () => {
          const r = await axe.run(document, {runOnly: {type: 'rule', values: ['color-contrast']}});
          return r.violations.flatMap((v) => v.nodes.map((n) => ({target: n.target.join(' '), summary: n.failureSummary})));
        }"""
    )
    return list(result)


def tabs_to_timeline(page: Any, max_tabs: int = 5) -> int:
    """Tab presses from the top of a freshly loaded page to the timeline's skip link; Enter then focuses the slider."""
    for presses in range(1, max_tabs + 1):
        page.keyboard.press("Tab")
        if page.evaluate("() => document.activeElement?.dataset.testid") == "skip-timeline":
            page.keyboard.press("Enter")
            assert page.evaluate("() => document.activeElement?.dataset.testid") == "slider"
            return presses
    raise AssertionError(f"the timeline's skip link is not within {max_tabs} Tab presses")
