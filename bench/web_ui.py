"""The web UI under a 300-step episode at 10 Hz: does the page keep up, and does its memory stay bounded?

A stand-in server (FastAPI on 127.0.0.1, no simulator or model) serves the built UI and streams LIBERO-spatial's
236 atoms with a random walk of flips, a JPEG per step, violations and subgoals, as protocol models. Chromium
(/usr/bin/chromium, Playwright) shows it. Measured in the page: animation-frame gaps while streaming (jank),
long tasks, how far the shown step lags the stream, the JS heap after 30 and after 300 steps, then the time a
keyboard step on the timeline slider takes to show (as Playwright sees it: includes the driver's round trip).
Targets: p95 frame gap <= 50 ms while streaming, lag <= 2 steps, heap growth 30 -> 300 steps <= 40 MB (the
frame cache is bounded), slider step p95 <= 100 ms (RAIL's input budget). One JSON line at the end.

    python bench/web_ui.py
"""

from __future__ import annotations

import asyncio
import base64
import io
import json
import shutil
import socket
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import uvicorn
from fastapi import FastAPI, WebSocket
from fastapi.staticfiles import StaticFiles
from PIL import Image

from quick import size
from vlaprobe.envs.spatial_scene import SPATIAL_SCENE
from vlaprobe.live import protocol as P
from vlaprobe.symbols import build_vocabulary

UI = Path(__file__).resolve().parents[1] / "src" / "vlaprobe" / "live" / "ui"
STEPS, HZ, MAX_FLIPS = size(300, 40), 10.0, 12
SCENE = SPATIAL_SCENE
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-precise-memory-info",
    "--js-flags=--expose-gc",
]


def frames(n: int = 30) -> list[str]:
    """Distinct 224x224 JPEGs (quality 90) of about a real frame's size."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:224, 0:224]
    out = []
    for i in range(n):
        img = np.stack([(x + 3 * i) % 256, (y * 2 + i) % 256, (x + y) % 256], -1).astype(np.float32)
        img += rng.normal(0, 6, img.shape)
        buf = io.BytesIO()
        Image.fromarray(img.clip(0, 255).astype(np.uint8)).save(buf, "JPEG", quality=90)
        out.append(base64.b64encode(buf.getvalue()).decode())
    return out


def episode() -> list[str]:
    """episode_start, STEPS steps, episode_end as JSON texts."""
    vocab = build_vocabulary(SCENE)
    obj, act = list(vocab.object_atoms), list(vocab.action_atoms)
    names = obj + act
    n = len(names)
    rng = np.random.default_rng(1)
    pred = rng.random(n) < 0.2
    truth = pred.copy()
    images = frames()
    subgoals = [P.SubgoalInfo(index=i, name=f"subgoal {i}") for i in range(4)]
    start = P.EpisodeStart(
        episode_id="bench",
        source="live",
        task=0,
        instruction="pick up the black bowl and place it on the plate",
        init=0,
        driver="expert",
        max_steps=STEPS,
        atoms=P.HeadNames(object=obj, action=act),
        probed=P.HeadFlags(object=[i % 9 != 8 for i in range(len(obj))], action=[True] * len(act)),
        subgoals=subgoals,
    )
    out = [start.model_dump_json()]
    for t in range(STEPS):
        before = pred.copy()
        flip = rng.choice(n, rng.integers(0, MAX_FLIPS + 1), replace=False)
        pred[flip] = ~pred[flip]
        truth[rng.choice(n, 2, replace=False)] ^= True
        on = [names[i] for i in np.flatnonzero(pred & ~before)]
        off = [names[i] for i in np.flatnonzero(~pred & before)]
        step = P.Step(
            episode_id="bench",
            t=t,
            image=images[t % len(images)],
            status=f"Executing step {t}",
            step=t,
            predicted=P.Prediction(
                object=P.HeadPrediction(values=pred[: len(obj)].astype(int).tolist(), probs=[0.5] * len(obj)),
                action=P.HeadPrediction(values=pred[len(obj) :].astype(int).tolist(), probs=[0.5] * len(act)),
            ),
            truth=P.HeadBits(
                object=truth[: len(obj)].astype(int).tolist(), action=truth[len(obj) :].astype(int).tolist()
            ),
            flips=P.Flips(predicted=P.FlipSet(on=on, off=off), truth=P.FlipSet(on=[], off=[])),
            beliefs=P.BeliefDelta(asserted=on, retracted=off),
            violations=[
                P.Violation(
                    rule=f"rule_{k}", message=f"rule {k} broken", atoms=names[k : k + 2], since=max(0, t - k)
                )
                for k in range(int(rng.integers(0, 8)))
            ],
            subgoals=[
                P.SubgoalState(index=g.index, name=g.name, status="done" if g.index < t // 80 else "active")
                for g in subgoals
            ],
            progress=min(1.0, t / STEPS),
            events=[P.Event(kind="subgoal_done", t=t, message="subgoal done")] if t % 80 == 79 else [],
            action=[0.0] * 7,
            predicted_action=None,
            timings=P.Timings(env_ms=1, model_ms=1, probes_ms=1, cognition_ms=1, total_ms=4),
        )
        out.append(step.model_dump_json())
    end = P.EpisodeEnd(
        episode_id="bench",
        success=True,
        steps=STEPS,
        stopped=False,
        summary=P.EpisodeSummary(
            violations={}, goal_step_predicted=None, goal_step_truth=None, agreement=0.9
        ),
    )
    out.append(end.model_dump_json())
    return out


def make_app(messages: list[str], sent: list[float]) -> FastAPI:
    app = FastAPI()
    hello = P.Hello(
        version="bench",
        tasks=[P.TaskInfo(index=0, instruction="pick up the black bowl and place it on the plate")],
        model_id="bench",
        probes=P.ProbeInfo(
            layers=P.HeadInts(object=0, action=0),
            threshold=0.5,
            atoms=P.HeadNames(object=[], action=[]),
            probed=P.HeadFlags(object=[], action=[]),
        ),
        image_hz=HZ,
        num_init_states=1,
        drivers=["expert", "policy"],
        default_driver="expert",
        running=None,
    )

    @app.get("/api/episodes")
    def episodes() -> list:
        return []

    @app.websocket("/ws")
    async def ws(sock: WebSocket) -> None:
        await sock.accept()
        await sock.send_text(hello.model_dump_json())
        await sock.receive_text()  # the start command
        t0 = time.perf_counter()
        for i, text in enumerate(messages):
            await asyncio.sleep(max(0.0, t0 + i / HZ - time.perf_counter()))
            await sock.send_text(text)
            sent.append(time.perf_counter())
        await sock.receive_text()

    app.mount("/", StaticFiles(directory=UI, html=True))
    return app


INIT = """
window.__gaps = []; window.__long = [];
let last = performance.now();
const tick = (now) => { window.__gaps.push(now - last); last = now; requestAnimationFrame(tick); };
requestAnimationFrame(tick);
new PerformanceObserver((l) => l.getEntries().forEach((e) => window.__long.push(e.duration)))
  .observe({ type: "longtask", buffered: true });
"""


def main() -> None:
    from playwright.sync_api import sync_playwright

    messages, sent = episode(), []
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(
        uvicorn.Config(make_app(messages, sent), host="127.0.0.1", port=port, log_level="error")
    )
    threading.Thread(target=server.run, daemon=True).start()
    while not server.started:
        time.sleep(0.05)
    profile = tempfile.mkdtemp(prefix="vlaprobe-bench-")
    try:
        with sync_playwright() as p:
            ctx = p.chromium.launch_persistent_context(
                profile,
                executable_path="/usr/bin/chromium",
                args=ARGS,
                headless=True,
                viewport={"width": 1400, "height": 1000},
            )
            page = ctx.new_page()
            page.add_init_script(INIT)
            page.goto(f"http://127.0.0.1:{port}/")
            page.wait_for_selector("[data-testid=connection][data-state=open]")
            page.click("[data-testid=start]")
            lags, heap30 = [], None
            while len(sent) < len(messages):
                time.sleep(0.1)
                shown = page.evaluate(
                    "() => { const s = document.querySelector('[data-testid=status]')?.textContent ?? '';"
                    " const m = s.match(/step (\\d+)/); return m ? Number(m[1]) : -1; }"
                )
                streamed = max(0, min(len(sent) - 2, STEPS - 1))
                if shown >= 0 and len(sent) > 1:
                    lags.append(streamed - shown)
                if heap30 is None and len(sent) > 31:
                    page.evaluate("() => window.gc && window.gc()")
                    heap30 = page.evaluate("() => performance.memory.usedJSHeapSize")
            page.wait_for_selector("[data-testid=timeline]")
            gaps = page.evaluate("() => window.__gaps.slice(5)")
            longs = page.evaluate("() => window.__long")
            page.evaluate("() => window.gc && window.gc()")
            heap300 = page.evaluate("() => performance.memory.usedJSHeapSize")
            slider = page.locator("[data-testid=slider]")
            slider.focus()
            page.keyboard.press("Home")
            times = []
            for k in range(1, min(60, STEPS)):  # quick mode: fewer steps than presses
                t0 = time.perf_counter()
                page.keyboard.press("ArrowRight")
                page.wait_for_function(
                    f"() => document.querySelector('[data-testid=step-indicator]').dataset.index === '{k}'"
                )
                times.append((time.perf_counter() - t0) * 1000)
            ctx.close()
    finally:
        shutil.rmtree(profile, ignore_errors=True)
        server.should_exit = True
    gaps_a = np.array(gaps)
    result = {
        "steps": STEPS,
        "hz": HZ,
        "frame_gap_p95_ms": round(float(np.percentile(gaps_a, 95)), 1),
        "frame_gap_max_ms": round(float(gaps_a.max()), 1),
        "long_tasks": len(longs),
        "long_task_max_ms": round(max(longs, default=0.0), 1),
        "lag_steps_p95": float(np.percentile(lags, 95)) if lags else None,
        "heap_mb_at_30_steps": round((heap30 or 0) / 2**20, 1),
        "heap_mb_at_300_steps": round(heap300 / 2**20, 1),
        "slider_step_ms_median": round(float(np.median(times)), 1),
        "slider_step_ms_p95": round(float(np.percentile(times, 95)), 1),
    }
    result["ok"] = bool(
        result["frame_gap_p95_ms"] <= 50
        and (result["lag_steps_p95"] or 0) <= 2
        and result["heap_mb_at_300_steps"] - result["heap_mb_at_30_steps"] <= 40
        and result["slider_step_ms_p95"] <= 100
    )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
