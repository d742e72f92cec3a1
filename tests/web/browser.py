"""The browser half of the end-to-end test: drives the web UI in Debian's chromium and checks what it shows
against the server's own records (GET /api/episodes/...). Used by test_browser.py on a real `vlaprobe serve`.
"""

from __future__ import annotations

import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.web.checks import (
    check_focused_view,
    check_frame,
    check_step,
    contrast_violations,
    get_json,
    shown_state,
    tabs_to_timeline,
)

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
    scrubbed_live: bool = False
    second_tab_synced: bool = False
    drop_text: str = ""
    focus: dict[str, int] = field(default_factory=dict)
    contrast: list[dict] | None = None
    tabs_to_timeline: int | None = None
    two_columns_at_1024: bool = False
    rerun_frames: int = 0
    reconnected: bool = False
    takeover_steps: list[int] = field(default_factory=list)
    """Steps checked in the takeover panel (a server with --takeover alarm)."""


def attach_console(page: Any, run: Run) -> None:
    page.on("console", lambda m: run.console_errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: run.console_errors.append(f"page error: {e}"))


def steps_shown(page: Any) -> int:
    return int(page.evaluate("() => document.querySelector('[data-testid=slider]')?.max ?? -1")) + 1


def scrub_live(page: Any, run: Run) -> None:
    """While the episode runs: move the slider back, see it stay there as steps arrive, then back to live."""
    slider = page.locator("[data-testid=slider]")
    box = slider.bounding_box()
    page.mouse.click(box["x"] + box["width"] * 0.2, box["y"] + box["height"] / 2)
    held = shown_state(page)
    if held["following"]:
        return  # the episode ended meanwhile
    n = steps_shown(page)
    page.wait_for_function(
        f"() => Number(document.querySelector('[data-testid=slider]').max) + 1 > {n + 2}", timeout=30_000
    )
    assert shown_state(page)["index"] == held["index"], "the scrubbed step moved while the episode ran"
    page.click("[data-testid=follow-live]")
    page.wait_for_function(
        "() => { const s = document.querySelector('[data-testid=step-indicator]').dataset;"
        " return s.following === '1' && Number(s.index) + 1 >= Number(document.querySelector('[data-testid=slider]').max); }",
        timeout=30_000,
    )
    run.scrubbed_live = True


def check_second_tab(page: Any, run: Run) -> None:
    """A page opened mid-episode (a reload, a second tab) shows the running episode's task, init and driver;
    from its top, the timeline's slider is a few Tab presses away (the skip link)."""
    other = page.context.new_page()
    attach_console(other, run)
    other.goto(run.base + "/")
    other.wait_for_selector("[data-testid=stream-banner][data-kind=live]", timeout=60_000)
    other.wait_for_function(
        "() => document.querySelector('[data-testid=init-select]').value === '0'", timeout=10_000
    )
    assert other.locator("[data-testid=task-select]").input_value() == "0"
    assert other.locator("[data-testid=start]").is_disabled()
    other.wait_for_selector("[data-testid=slider]", timeout=30_000)
    run.tabs_to_timeline = tabs_to_timeline(other)  # from the top of a freshly loaded page
    run.second_tab_synced = True
    other.close()


def watch_live_episode(page: Any, run: Run, max_steps: int, timeout_s: float) -> None:
    """Start task 0; collect frames and a just-turned-true atom, scrub back live, drop; until the end."""
    page.wait_for_selector("[data-testid=connection][data-state=open]", timeout=30_000)
    page.select_option("[data-testid=task-select]", "0")
    page.select_option("[data-testid=init-select]", "0")
    page.fill("input[placeholder=server]", str(max_steps))
    page.click("[data-testid=start]")
    page.wait_for_selector("[data-testid=stream-banner][data-kind=live]", timeout=int(timeout_s * 1000))
    assert page.locator("[data-testid=start]").is_disabled(), "Start stays enabled during a run"
    frames: set[str] = set()
    screenshot_taken = dropped = False
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not page.query_selector("[data-testid=summary]"):
        src = page.evaluate(
            "() => document.querySelector('[data-testid=camera]')?.getAttribute('src') ?? null"
        )
        if src:
            frames.add(src)
        if run.saw_turned_on is None:
            run.saw_turned_on = page.evaluate(
                "() => document.querySelector('[data-testid=atom][data-state=turned-on]')?.dataset.atom ?? null"
            )
        n = steps_shown(page)
        if not run.scrubbed_live and n >= 8:
            scrub_live(page, run)
            check_second_tab(page, run)
        if not dropped and n >= 14:
            page.fill("input[aria-label='drop steps']", "6")
            page.click("[data-testid=drop]")
            page.wait_for_selector("[data-testid=drop-indicator][data-active='1']", timeout=30_000)
            run.drop_text = page.locator("[data-testid=drop-indicator]").inner_text()
            dropped = True
        if run.saw_turned_on and len(frames) >= 10 and not screenshot_taken and dropped:
            page.screenshot(path=str(run.out / "live-view.png"))
            screenshot_taken = True
        time.sleep(0.03)
    run.distinct_frames = len(frames)
    if not screenshot_taken:
        page.screenshot(path=str(run.out / "live-view.png"))


def go_to(page: Any, k: int) -> None:
    """Step index k by keyboard on the focused slider: Home, PageUp by 10, arrows by 1."""
    page.locator("[data-testid=slider]").focus()
    page.keyboard.press("Home")
    for _ in range(k // 10):
        page.keyboard.press("PageUp")
    for _ in range(k % 10):
        page.keyboard.press("ArrowRight")
    assert shown_state(page)["index"] == k


def scrub_and_check(page: Any, run: Run, record: dict) -> None:
    """Slider by mouse and keyboard (PageUp = 10 steps), and a click on the raster: each shows the recorded step."""
    n = len(record["steps"])
    page.check("[data-testid=show-unprobed]")  # every atom on the page, for check_step
    slider = page.locator("[data-testid=slider]")
    box = slider.bounding_box()
    page.mouse.click(box["x"] + box["width"] * 0.3, box["y"] + box["height"] / 2)
    check_step(page, run.base, record, shown_state(page)["index"])
    k = n // 2
    go_to(page, k)
    check_step(page, run.base, record, k)
    run.checked_steps.append(k)
    raster = page.locator("[data-testid=raster]")
    d = raster.evaluate("(e) => ({...e.dataset})")
    marker = page.locator("[data-testid=raster-marker]").evaluate("(e) => e.offsetLeft")
    assert abs(marker - (float(d["left"]) + k * float(d["cellWidth"]))) <= 1, marker
    target = max(0, n // 4)
    x = float(d["left"]) + (target + 0.5) * float(d["cellWidth"])
    raster.click(position={"x": x, "y": float(d["top"]) + float(d["cellHeight"]) / 2})
    check_step(page, run.base, record, target)
    run.checked_steps.append(target)
    slider.focus()
    page.keyboard.press("PageUp")
    assert shown_state(page)["index"] == min(n - 1, target + 10), "PageUp is not 10 steps"
    go_to(page, k)  # back to the middle, for the focused view and the screenshots
    run.focus = check_focused_view(page, record, k)
    run.checked_steps.append(k)


def check_layout(page: Any, run: Run) -> None:
    """At 1024 px the beliefs keep two columns; zoom widens the raster's steps; a greyscale screenshot."""
    page.set_viewport_size({"width": 1024, "height": 700})
    page.wait_for_timeout(300)
    tops = page.evaluate(
        "() => [...document.querySelectorAll('[data-testid=others] [data-testid=atom]')].slice(0, 2).map((e) => [e.offsetTop, e.offsetLeft])"
    )
    run.two_columns_at_1024 = len(tops) == 2 and tops[0][0] == tops[1][0] and tops[0][1] != tops[1][1]
    page.screenshot(path=str(run.out / "layout-1024.png"))
    page.set_viewport_size({"width": 1400, "height": 1000})
    raster = page.locator("[data-testid=raster]")
    fit = float(raster.get_attribute("data-cell-width") or 0)
    page.click("[data-testid=zoom-in]")
    assert float(raster.get_attribute("data-cell-width") or 0) > fit, "zoom in did not widen the steps"
    page.click("[data-testid=zoom-fit]")
    page.add_style_tag(content="html { filter: grayscale(1); }")
    page.locator("[data-testid=timeline]").screenshot(path=str(run.out / "timeline-greyscale.png"))
    page.evaluate(
        "() => document.querySelectorAll('style').forEach((s) => s.textContent.includes('grayscale') && s.remove())"
    )


def check_rerun(page: Any, run: Run, timeout_s: float) -> None:
    """A store episode re-run through the probes: banner, Drop disabled, and every frame shown afterwards."""
    item = page.locator("[data-testid=episode]", has=page.locator("[data-testid=stream-episode]")).first
    store_id = item.get_attribute("data-id")
    item.locator("[data-testid=stream-episode]").click()
    page.wait_for_selector("[data-testid=stream-banner][data-kind='store re-run']", timeout=60_000)
    assert page.locator("[data-testid=drop]").is_disabled(), "Drop is enabled during a store re-run"
    page.wait_for_selector("[data-testid=summary]", timeout=int(timeout_s * 1000))
    record = get_json(f"{run.base}/api/episodes/{store_id}")
    assert page.evaluate("() => document.querySelector('[data-testid=stream-banner]').textContent").count(
        store_id
    )
    slider = page.locator("[data-testid=slider]")
    slider.focus()
    page.keyboard.press("Home")
    for k, step in enumerate(record["steps"]):
        page.wait_for_function(
            "() => { const i = document.querySelector('[data-testid=camera]'); return i && i.complete && i.naturalWidth > 0; }",
            timeout=10_000,
        )
        check_frame(run.base, store_id, shown_state(page), step["t"])
        run.rerun_frames += 1
        if k < len(record["steps"]) - 1:
            page.keyboard.press("ArrowRight")


def reconnect(page: Any, run: Run, restart: Callable[[], None]) -> None:
    """The server restarts: the page shows it is reconnecting and comes back by itself.

    While the server is down Chromium logs each failed WebSocket attempt as a console error: those, and only
    those, are expected.
    """
    before = len(run.console_errors)
    restart_thread = threading.Thread(target=restart)
    restart_thread.start()
    page.wait_for_selector("[data-testid=connection][data-state=reconnecting]", timeout=30_000)
    restart_thread.join()
    page.wait_for_selector("[data-testid=connection][data-state=open]", timeout=60_000)
    outage = run.console_errors[before:]
    del run.console_errors[before:]
    run.console_errors += [e for e in outage if "WebSocket connection to" not in e]


def check_reconnect(page: Any, run: Run, restart: Callable[[], None]) -> None:
    """The server restarts: the page reconnects by itself and lists the recording again."""
    reconnect(page, run, restart)
    page.wait_for_selector(f"[data-testid=episode][data-id='{run.episode_id}']", timeout=30_000)
    run.reconnected = True


def check_takeover(
    page: Any, run: Run, restart: Callable[[], None], max_steps: int, timeout_s: float
) -> None:
    """The server restarts with ``--takeover alarm``: a policy episode runs, and at a step under the expert the
    panel says the expert acts (which takeover, which action, why) with the alarms so far; at the alarm's own
    step the policy acts. Compared with the server's record."""
    reconnect(page, run, restart)
    page.wait_for_function(
        "() => [...document.querySelectorAll('[data-testid=driver-select] option')].map((o) => o.value).join() === 'policy'",
        timeout=30_000,
    )
    page.select_option("[data-testid=task-select]", "0")
    page.select_option("[data-testid=init-select]", "0")
    page.fill("input[placeholder=server]", str(max_steps))
    page.click("[data-testid=start]")
    page.wait_for_function(
        "() => document.querySelector('[data-testid=stream-banner]')?.textContent.includes('takeover alarm')",
        timeout=int(timeout_s * 1000),
    )
    page.wait_for_selector("[data-testid=summary]", timeout=int(timeout_s * 1000))
    live = [e for e in get_json(f"{run.base}/api/episodes") if e["source"] == "live"]
    newest = max(live, key=lambda e: e["created"] + e["id"])["id"]
    steps = get_json(f"{run.base}/api/episodes/{newest}")["steps"]
    under = [k for k, s in enumerate(steps) if s["takeover"] is not None]
    assert under, "no takeover in the episode: the check proves nothing"
    for k in (under[0], under[-1]):
        go_to(page, k)
        t = steps[k]["takeover"]
        acting = page.locator("[data-testid=acting]")
        assert acting.get_attribute("data-who") == "expert", k
        text = acting.inner_text()
        assert f"takeover {t['index']}, action {t['steps']} of" in text and t["reason"] in text, text
        alarms = [s["alarm"] for s in steps[: k + 1] if s["alarm"] is not None]
        shown = page.locator("[data-testid=alarms] li.alarm").all_inner_texts()
        assert len(shown) == len(alarms) and alarms[-1]["reason"] in shown[0], shown
        run.takeover_steps.append(k)
    page.screenshot(path=str(run.out / "takeover.png"))
    go_to(page, under[0] - 1)  # the alarm's step: the policy executed its action
    assert page.locator("[data-testid=acting]").get_attribute("data-who") == "policy"


def open_and_replay(page: Any, run: Run, record: dict, timeout_s: float) -> None:
    """The recorded episode from the episodes list: opened at step 0, then replayed to its end."""
    page.click("[data-testid=refresh-episodes]")
    item = page.locator(f"[data-testid=episode][data-id='{run.episode_id}']")
    item.locator("[data-testid=open-episode]").click()
    page.wait_for_selector("[data-testid=stream-banner][data-kind=recorded]")
    check_step(page, run.base, record, 0)
    item.locator("[data-testid=replay-episode]").click()
    last = len(record["steps"]) - 1
    page.wait_for_function(  # plays at the stream's rate, then stops at the last step
        f"() => Number(document.querySelector('[data-testid=step-indicator]').dataset.index) == {last}",
        timeout=int(timeout_s * 1000),
    )
    check_step(page, run.base, record, last)
    run.checked_steps += [0, last]
    page.click("[data-testid=back-to-live]")


def run_browser(
    base: str,
    out: Path,
    *,
    max_steps: int = 30,
    min_steps: int = 10,
    episode_timeout_s: float = 240,
    restart: Callable[[], None] | None = None,
    rerun: bool = True,
    takeover: Callable[[], None] | None = None,
) -> Run:
    """The whole end-to-end scenario against the server at ``base``; screenshots go to ``out``.

    ``restart`` (optional) restarts the server on the same port, for the reconnect check at the end; ``rerun``
    re-runs the first store episode (the server needs ``--store``); ``takeover`` (optional) restarts it with
    ``--driver policy --takeover alarm``, for the takeover panel's check last.
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
            listed = get_json(f"{base}/api/episodes")
            live = [e for e in listed if e["source"] == "live"]
            assert live, listed
            run.episode_id = max(live, key=lambda e: e["created"] + e["id"])["id"]
            record = get_json(f"{base}/api/episodes/{run.episode_id}")
            assert record["end"] is not None and len(record["steps"]) >= min_steps
            run.contrast = contrast_violations(page)
            scrub_and_check(page, run, record)
            page.screenshot(path=str(out / "timeline.png"))
            check_layout(page, run)
            open_and_replay(page, run, record, episode_timeout_s)
            if rerun:
                check_rerun(page, run, episode_timeout_s)
            if restart is not None:
                check_reconnect(page, run, restart)
            if takeover is not None:
                check_takeover(page, run, takeover, 16, episode_timeout_s)
            ctx.close()
    finally:
        shutil.rmtree(profile, ignore_errors=True)
    return run


if __name__ == "__main__":
    # The screenshot of docs/live.md, made with trained probes: against a running `vlaprobe serve` (defaults:
    # runs/default/probes), `python -m tests.web.browser http://127.0.0.1:6006 OUT` runs the test's scenario
    # (a 60-step expert episode of task 0) and writes live-view.png and timeline.png to OUT; docs/img/live-view.png
    # is OUT/live-view.png. With --store on the server, the store re-run is checked too.
    import sys

    if len(sys.argv) != 3:
        sys.exit("usage: python -m tests.web.browser BASE_URL OUT_DIR")
    base_url = sys.argv[1].rstrip("/")
    has_store = any(e["source"] == "store" for e in get_json(f"{base_url}/api/episodes"))
    seen = run_browser(base_url, Path(sys.argv[2]), max_steps=60, rerun=has_store)
    print({k: v for k, v in vars(seen).items() if k not in ("base", "out")})
    if seen.console_errors:
        sys.exit(f"console errors: {seen.console_errors}")
