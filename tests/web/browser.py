"""The browser half of the end-to-end test: drives the web UI in Debian's chromium and checks what it shows
against the server's own records (GET /api/episodes/...). Used by test_browser.py on a real `vlaprobe serve`.
"""

from __future__ import annotations

import base64
import json
import shutil
import tempfile
import threading
import time
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
FADE_STEPS = 5
"""web/src/lib/flips.ts DEFAULT_FADE_STEPS: steps an atom stays marked as just flipped."""


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


@dataclass
class Run:
    """What one browser session saw."""

    base: str
    out: Path
    console_errors: list[str] = field(default_factory=list)
    distinct_frames: int = 0
    saw_turned_on: str | None = None
    episode_id: str | None = None
    checked_steps: list[int] = field(default_factory=list)
    reconnected: bool = False


def attach_console(page: Any, run: Run) -> None:
    page.on("console", lambda m: run.console_errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: run.console_errors.append(f"page error: {e}"))


def watch_live_episode(page: Any, run: Run, max_steps: int, timeout_s: float) -> None:
    """Start task 0 from the control bar; collect distinct frames and an atom just turned true until the end."""
    page.wait_for_selector("[data-testid=connection][data-state=open]", timeout=30_000)
    page.select_option("[data-testid=task-select]", "0")
    page.fill("input[placeholder=server]", str(max_steps))
    page.click("[data-testid=start]")
    frames: set[str] = set()
    screenshot_taken = False
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        src = page.evaluate(
            "() => document.querySelector('[data-testid=camera]')?.getAttribute('src') ?? null"
        )
        if src:
            frames.add(src)
        if run.saw_turned_on is None:
            run.saw_turned_on = page.evaluate(
                "() => document.querySelector('[data-testid=atom][data-state=turned-on]')?.dataset.atom ?? null"
            )
        if run.saw_turned_on and len(frames) >= 10 and not screenshot_taken:
            page.screenshot(path=str(run.out / "live-view.png"))
            screenshot_taken = True
        if page.query_selector("[data-testid=timeline]"):
            break
        time.sleep(0.03)
    run.distinct_frames = len(frames)
    if not screenshot_taken:
        page.screenshot(path=str(run.out / "live-view.png"))


def shown_state(page: Any) -> dict[str, Any]:
    return page.evaluate(
        """() => ({
          index: Number(document.querySelector('[data-testid=step-indicator]').dataset.index),
          t: Number(document.querySelector('[data-testid=step-indicator]').dataset.t),
          src: document.querySelector('[data-testid=camera]')?.getAttribute('src') ?? null,
          agreement: document.querySelector('[data-testid=agreement]').textContent,
          atoms: [...document.querySelectorAll('[data-testid=atom]')].map(
            (e) => [e.dataset.atom, e.dataset.state, e.dataset.agree]),
          violations: [...document.querySelectorAll('[data-testid=violations] [data-rule]')].map(
            (e) => e.dataset.rule),
        })"""
    )


def check_step(page: Any, run: Run, record: dict, k: int) -> None:
    """The image, atom states, agreement and violations shown equal the server's recorded step k."""
    shown = shown_state(page)
    steps = record["steps"]
    step = steps[k]
    assert shown["index"] == k and shown["t"] == step["t"], (shown["index"], shown["t"], k)
    frame = get_bytes(f"{run.base}/api/episodes/{run.episode_id}/frames/{step['t']}")
    src = shown["src"]
    assert src, "no image shown"
    if src.startswith("data:image/jpeg;base64,"):
        assert base64.b64decode(src.split(",", 1)[1]) == frame, (
            f"image at step {k} differs from the recording"
        )
    else:
        assert src.split("?")[0].endswith(f"/api/episodes/{run.episode_id}/frames/{step['t']}"), src
    names = record["start"]["atoms"]["object"] + record["start"]["atoms"]["action"]
    predicted = [bits(s, "predicted") for s in steps]
    states = expected_states(predicted, k)  # type: ignore[arg-type]
    got = {a: (s, agree) for a, s, agree in shown["atoms"]}
    assert set(got) == set(names)
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
    run.checked_steps.append(k)


def scrub_and_check(page: Any, run: Run, record: dict) -> None:
    """Slider by mouse and keyboard, and a click on the raster: each shows the recorded step."""
    n = len(record["steps"])
    slider = page.locator("[data-testid=slider]")
    box = slider.bounding_box()
    page.mouse.click(box["x"] + box["width"] * 0.3, box["y"] + box["height"] / 2)
    check_step(page, run, record, shown_state(page)["index"])
    k = n // 2
    slider.focus()
    page.keyboard.press("Home")
    for _ in range(k):
        page.keyboard.press("ArrowRight")
    check_step(page, run, record, k)
    predicted = bits(record["steps"][k], "predicted") or []
    page.check("[data-testid=filter-true]")  # the filters: true atoms only, then those changed at this step
    assert page.locator("[data-testid=atom]").count() == sum(predicted)
    page.check("[data-testid=filter-changed]")
    changed = sum(
        a != b for a, b in zip(predicted, bits(record["steps"][k - 1], "predicted") or [], strict=True)
    )
    assert page.locator("[data-testid=atom]").count() == changed
    page.check("[data-testid=filter-all]")
    raster = page.locator("[data-testid=raster]")
    d = raster.evaluate("(e) => ({...e.dataset})")
    marker = page.locator("[data-testid=raster-marker]").evaluate("(e) => e.offsetLeft")
    assert abs(marker - (float(d["left"]) + k * float(d["cellWidth"]))) <= 1, marker
    target = max(0, n // 4)
    x = float(d["left"]) + (target + 0.5) * float(d["cellWidth"])
    raster.click(position={"x": x, "y": float(d["cellHeight"]) / 2})
    check_step(page, run, record, target)
    # back to k for the timeline screenshot
    slider.focus()
    page.keyboard.press("Home")
    for _ in range(k):
        page.keyboard.press("ArrowRight")


def check_reconnect(page: Any, run: Run, restart: Callable[[], None]) -> None:
    """The server restarts: the page shows it is reconnecting, comes back by itself and lists the recording.

    While the server is down Chromium logs each failed WebSocket attempt as a console error: those, and only
    those, are expected.
    """
    before = len(run.console_errors)
    restart_thread = threading.Thread(target=restart)
    restart_thread.start()
    page.wait_for_selector("[data-testid=connection][data-state=reconnecting]", timeout=30_000)
    restart_thread.join()
    page.wait_for_selector("[data-testid=connection][data-state=open]", timeout=60_000)
    page.wait_for_selector(f"[data-testid=episode][data-id='{run.episode_id}']", timeout=30_000)
    outage = run.console_errors[before:]
    del run.console_errors[before:]
    run.console_errors += [e for e in outage if "WebSocket connection to" not in e]
    run.reconnected = True


def run_browser(
    base: str,
    out: Path,
    *,
    max_steps: int = 30,
    min_steps: int = 10,
    episode_timeout_s: float = 240,
    restart: Callable[[], None] | None = None,
) -> Run:
    """The whole end-to-end scenario against the server at ``base``; screenshots go to ``out``.

    ``restart`` (optional) restarts the server on the same port, for the reconnect check at the end.
    """
    from playwright.sync_api import sync_playwright

    out.mkdir(parents=True, exist_ok=True)
    run = Run(base=base, out=out)
    profile = Path(tempfile.mkdtemp(prefix="vlaprobe-chromium-"))
    try:
        with sync_playwright() as p:
            ctx = p.chromium.launch_persistent_context(
                str(profile),
                executable_path=str(CHROMIUM),
                args=CHROMIUM_ARGS,
                headless=True,
                viewport={"width": 1400, "height": 1000},
            )
            page = ctx.new_page()
            attach_console(page, run)
            page.goto(base + "/")
            watch_live_episode(page, run, max_steps, episode_timeout_s)
            page.wait_for_selector("[data-testid=timeline]", timeout=int(episode_timeout_s * 1000))
            listed = get_json(f"{base}/api/episodes")
            live = [e for e in listed if e["source"] == "live"]
            assert live, listed
            run.episode_id = max(live, key=lambda e: e["created"] + e["id"])["id"]
            record = get_json(f"{base}/api/episodes/{run.episode_id}")
            assert record["end"] is not None and len(record["steps"]) >= min_steps
            scrub_and_check(page, run, record)
            page.screenshot(path=str(out / "timeline.png"))

            # The recorded episode from the episodes list: opened at step 0, then replayed to its end.
            page.click("[data-testid=refresh-episodes]")
            item = page.locator(f"[data-testid=episode][data-id='{run.episode_id}']")
            item.locator("[data-testid=open-episode]").click()
            page.wait_for_selector("[data-testid=back-to-live]")
            check_step(page, run, record, 0)
            item.locator("[data-testid=replay-episode]").click()
            last = len(record["steps"]) - 1
            page.wait_for_function(  # plays at the stream's rate, then stops at the last step
                f"() => Number(document.querySelector('[data-testid=step-indicator]').dataset.index) == {last}",
                timeout=int(episode_timeout_s * 1000),
            )
            check_step(page, run, record, last)
            page.click("[data-testid=back-to-live]")
            if restart is not None:
                check_reconnect(page, run, restart)
            ctx.close()
    finally:
        shutil.rmtree(profile, ignore_errors=True)
    return run


if __name__ == "__main__":
    # The README's screenshot, made with trained probes: against a running `vlaprobe serve` (defaults:
    # runs/default/probes), `python -m tests.web.browser http://127.0.0.1:6006 OUT` runs the test's scenario
    # (a 60-step expert episode of task 0) and writes live-view.png and timeline.png to OUT; docs/img/live-view.png
    # is OUT/live-view.png.
    import sys

    if len(sys.argv) != 3:
        sys.exit("usage: python -m tests.web.browser BASE_URL OUT_DIR")
    seen = run_browser(sys.argv[1].rstrip("/"), Path(sys.argv[2]), max_steps=60)
    if seen.console_errors:
        sys.exit(f"console errors: {seen.console_errors}")
    print(f"{seen.distinct_frames} frames, steps checked {seen.checked_steps}; screenshots in {sys.argv[2]}")
