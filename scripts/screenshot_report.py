"""A picture of a report page for the README: one of its figures (headless Chromium through Playwright).

.venv/bin/python scripts/screenshot_report.py runs/default/report/index.html docs/img/report.png
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

CHROMIUM = Path("/usr/bin/chromium")


def screenshot(page: Path, out: Path, selector: str, width: int = 1200, height: int = 900) -> Path:
    """Render ``page`` (a local HTML file) at ``width`` x ``height`` and save the element ``selector`` (the
    first screen when it is empty) as PNG."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p, tempfile.TemporaryDirectory(prefix="vlaprobe-chromium-") as profile:
        ctx = p.chromium.launch_persistent_context(
            profile,
            executable_path=str(CHROMIUM),
            args=["--no-sandbox", "--disable-gpu"],
            headless=True,
            viewport={"width": width, "height": height},
        )
        tab = ctx.new_page()
        tab.goto(page.resolve().as_uri())
        tab.wait_for_load_state("networkidle")
        out.parent.mkdir(parents=True, exist_ok=True)
        if selector:
            tab.locator(selector).first.screenshot(path=str(out))
        else:
            tab.screenshot(path=str(out))
        ctx.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("page", type=Path, help="the report's index.html")
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument(
        "--selector", default="#curves_object", help="the element to capture ('': the screen)"
    )
    parser.add_argument("--width", type=int, default=1200)
    parser.add_argument("--height", type=int, default=900)
    args = parser.parse_args(argv)
    if not args.page.is_file():
        print(
            f"screenshot_report: no {args.page}; pass a report page written by vlaprobe report",
            file=sys.stderr,
        )
        return 2
    print(f"wrote {screenshot(args.page, args.out, args.selector, args.width, args.height)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
