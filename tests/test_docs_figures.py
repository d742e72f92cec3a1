"""Every figure the README and docs quote with a marker equals the published results file it names.

A marker follows the number it checks and renders invisibly:
``**0.917**<!-- fig:default:object.best.value -->`` names ``docs/results/default.json`` (written by ``scripts/publish_results.py`` from a run's ``results.json``)
and a key of it. The quoted number must equal the file's figure rounded to the quoted decimals (a unicode
minus and a leading + are allowed); an unknown file or key, or a marker with no number before it, fails.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from vlaprobe.errors import VlaprobeError
from vlaprobe.results import RunResults, read_results, write_results

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
RESULTS = ROOT / "docs" / "results"
MARKER = re.compile(r"<!--\s*fig:(?P<name>[\w-]+):(?P<key>[\w.]+)\s*-->")
QUOTED = re.compile(r"(?P<number>[−+-]?\d+(?:\.\d+)?)%?\**\s*$")
README_LIMIT = 12 * 1024
HEADLINE = [
    "object.best.value",
    "object.task_time_baseline.value",
    "action.best.value",
    "action.task_time_baseline.value",
    "cognition.goal.recall",
    "cognition.goal.precision",
]
"""Figures the README's headline must quote with a marker."""


FENCED = re.compile(r"^```.*?^```", re.S | re.M)
INLINE_CODE = re.compile(r"`[^`\n]*`")


def _prose(text: str) -> str:
    """``text`` with code blocks and code spans blanked (same lines and offsets): a marker there is an
    example, not a quoted figure."""
    text = FENCED.sub(lambda m: re.sub(r"[^\n]", " ", m[0]), text)
    return INLINE_CODE.sub(lambda m: " " * len(m[0]), text)


def markers(text: str) -> list[tuple[str | None, str, str, int]]:
    """(quoted number or None, results name, key, line) of every marker in ``text`` outside code."""
    text = _prose(text)
    found = []
    for m in MARKER.finditer(text):
        before = QUOTED.search(text[max(0, m.start() - 40) : m.start()])
        line = text.count("\n", 0, m.start()) + 1
        found.append((None if before is None else before["number"], m["name"], m["key"], line))
    return found


def check(text: str, where: str, results_dir: Path = RESULTS) -> list[str]:
    """One line per marker whose quoted number disagrees with its results file (empty: all agree)."""
    loaded: dict[str, RunResults] = {}
    problems = []
    for quoted, name, key, line in markers(text):
        at = f"{where}:{line} fig:{name}:{key}"
        if quoted is None:
            problems.append(f"{at}: no number right before the marker")
            continue
        try:
            results = loaded.get(name) or read_results(results_dir / f"{name}.json")
            loaded[name] = results
            value = results.figure(key)
        except VlaprobeError as exc:
            problems.append(f"{at}: {exc}")
            continue
        if value is None:
            problems.append(f"{at}: the figure is undefined in {name}.json")
            continue
        number = quoted.replace("−", "-").lstrip("+")
        decimals = len(number.split(".")[1]) if "." in number else 0
        expected = f"{value:.{decimals}f}"
        if float(number) != float(expected):
            problems.append(f"{at}: quoted {quoted}, {name}.json has {value} ({expected})")
    return problems


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_quoted_figures_match_the_results_file(path: Path) -> None:
    problems = check(path.read_text(), str(path.relative_to(ROOT)))
    assert not problems, (
        "quoted figures disagree with docs/results (scripts/publish_results.py):\n" + "\n".join(problems)
    )


def test_the_readme_marks_its_headline_and_stays_short() -> None:
    text = (ROOT / "README.md").read_text()
    marked = {key for _, name, key, _ in markers(text) if name == "default"}
    assert not set(HEADLINE) - marked, f"unmarked headline figures: {sorted(set(HEADLINE) - marked)}"
    assert len(text.encode()) <= README_LIMIT, "the README is the front door: move detail into docs/"


def test_every_published_file_reads() -> None:
    files = sorted(RESULTS.glob("*.json"))
    assert files, "docs/results holds the default run's figures"
    for path in files:
        read_results(path)


def test_the_check_catches_wrong_unknown_and_unanchored_figures(tmp_path: Path) -> None:
    figures: dict[str, float | int | None] = {"object.best.value": 0.91666, "object.best.layer": 30}
    figures["object.selectivity.value"] = -0.0194
    figures["cognition.goal.recall"] = None
    write_results(tmp_path, RunResults("m", None, "0", figures), name="t.json")

    def problems(text: str) -> list[str]:
        return check(text, "x.md", tmp_path)

    assert (
        problems("best **0.917**<!-- fig:t:object.best.value --> at 30<!-- fig:t:object.best.layer -->") == []
    )
    assert (
        problems("0.92 <!-- fig:t:object.best.value -->, −0.019<!-- fig:t:object.selectivity.value -->") == []
    )
    assert problems("1,0.9167<!--fig:t:object.best.value-->") == []
    assert "quoted 0.918" in problems("**0.918**<!-- fig:t:object.best.value -->")[0]
    assert "quoted 0.019" in problems("0.019<!-- fig:t:object.selectivity.value -->")[0]
    assert "quoted 31" in problems("layer 31<!-- fig:t:object.best.layer -->")[0]
    assert "no figure 'object.nope'" in problems("0.9<!-- fig:t:object.nope -->")[0]
    assert "no " in problems("0.9<!-- fig:missing:object.best.value -->")[0]
    assert "no number" in problems("best <!-- fig:t:object.best.value -->")[0]
    assert "undefined" in problems("0.5<!-- fig:t:cognition.goal.recall -->")[0]
    assert markers("a 1<!-- fig:t:a.b -->\nb 2<!-- fig:t:c.d -->")[1] == ("2", "t", "c.d", 2)
    example = "```md\n**0.5**<!-- fig:t:object.best.value -->\n```\n`0.5<!-- fig:t:x -->` 7<!-- fig:t:y.z -->"
    assert markers(example) == [("7", "t", "y.z", 4)]  # markers in code are examples, not checked
