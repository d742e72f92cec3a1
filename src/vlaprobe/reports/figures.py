"""Matplotlib figures of the report (Agg backend, no display needed), rendered to PNG and SVG bytes."""

from __future__ import annotations

import io
from dataclasses import dataclass

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # after use("Agg"): no display needed
import numpy as np

plt.rcParams["svg.hashsalt"] = "vlaprobe"  # stable SVG ids: the same data gives the same file


def metric_label(metric: str) -> str:
    """Display name of a metric: "balanced_accuracy" -> "balanced accuracy", "auprc" -> "AUPRC"."""
    return {"auprc": "AUPRC", "f1": "F1"}.get(metric, metric.replace("_", " "))


@dataclass
class Rendered:
    """One figure in both formats."""

    png: bytes
    svg: bytes


def _render(fig: plt.Figure, dpi: int) -> Rendered:
    out = []
    for fmt in ("png", "svg"):
        buf = io.BytesIO()
        fig.savefig(
            buf, format=fmt, dpi=dpi, bbox_inches="tight", metadata={"Date": None} if fmt == "svg" else None
        )
        out.append(buf.getvalue())
    plt.close(fig)
    return Rendered(png=out[0], svg=out[1])


@dataclass
class TieMarks:
    """One head's block of heatmap columns and the rows to mark on its left: the layers tied with its best."""

    first_column: int
    rows: list[int]
    """Rows (positions) of the tied layers, the best included."""
    best_row: int
    tied_layers: list[int]
    """The same layers as hidden-state indices (for the figure's data file)."""
    best_layer: int


def _mark_ties(ax: plt.Axes, marks: dict[str, TieMarks]) -> None:
    """▸ at the left edge of each head's first column at its tied layers, ★ at its best (beside the values)."""
    for m in marks.values():
        x = m.first_column - 0.36
        others = [r for r in m.rows if r != m.best_row]
        for xs, ys, marker, size in (([x] * len(others), others, ">", 5), ([x], [m.best_row], "*", 9)):
            ax.plot(
                xs, ys, marker, markersize=size, color="black", markeredgecolor="white", markeredgewidth=0.5
            )


def heatmap(
    values: np.ndarray,
    layers: list[int],
    columns: list[str],
    title: str,
    colorbar: str,
    dpi: int,
    split_after: int | None = None,
    vmin: float | None = None,
    vmax: float | None = None,
    cmap: str = "viridis",
    marks: dict[str, TieMarks] | None = None,
) -> Rendered:
    """Layers (rows, first at the top) x columns, every cell annotated with its value (blank if undefined).

    ``split_after``: number of leading columns after which a vertical line separates two groups
    (object predicates | action predicates). ``marks``: per head, the layers tied with its best, marked
    left of its columns.
    """
    rows, cols = values.shape
    fig, ax = plt.subplots(figsize=(1.6 + 0.72 * cols, 1.4 + 0.27 * rows))
    masked = np.ma.masked_invalid(values)
    image = ax.imshow(masked, aspect="auto", cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
    low = np.nanmin(values) if np.isfinite(values).any() else 0.0
    high = np.nanmax(values) if np.isfinite(values).any() else 1.0
    middle = (low + high) / 2 if vmin is None or vmax is None else (vmin + vmax) / 2
    for i in range(rows):
        for j in range(cols):
            v = values[i, j]
            if np.isfinite(v):
                ax.text(
                    j,
                    i,
                    f"{v:.2f}",
                    ha="center",
                    va="center",
                    fontsize=6,
                    color="black" if v > middle else "white",
                )
    ax.set_xticks(range(cols), columns, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(rows), [str(layer) for layer in layers], fontsize=6)
    ax.set_ylabel("layer (hidden state)")
    if split_after is not None and 0 < split_after < cols:
        ax.axvline(split_after - 0.5, color="white", linewidth=2)
    if marks:
        _mark_ties(ax, marks)
    ax.set_title(title, fontsize=10)
    fig.colorbar(image, ax=ax, fraction=0.04, pad=0.02, label=colorbar)
    return _render(fig, dpi)


PANELS_PER_ROW = 4
"""The most panels :func:`curves` puts side by side."""


@dataclass
class Series:
    """One line of a curve plot: values per layer (or per ``x``) with an optional band (a 95% interval, or
    quartiles)."""

    label: str
    value: np.ndarray
    low: np.ndarray | None = None
    high: np.ndarray | None = None
    style: str = "-"
    x: np.ndarray | None = None
    """The line's own x values (a ROC curve's false-positive rates); default: the plot's shared x."""


def curves(
    panels: dict[str, list[Series]],
    layers: list[int] | np.ndarray,
    title: str,
    dpi: int,
    xlabel: str = "layer",
    ylabel: str = "",
) -> Rendered:
    """One panel per metric, metric versus layer (or ``xlabel``), each series a line with its band; at most
    ``PANELS_PER_ROW`` panels a row, so that many panels stay readable at the page's width."""
    n = len(panels)
    cols = min(n, PANELS_PER_ROW)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.2 * rows), squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_axis_off()
    shared = np.asarray(layers)
    for ax, (metric, series) in zip(axes.flat[:n], panels.items(), strict=True):
        for s in series:
            x = shared if s.x is None else np.asarray(s.x)
            (line,) = ax.plot(x, s.value, s.style, label=s.label, linewidth=1.4, markersize=3)
            if s.low is not None and s.high is not None:
                ax.fill_between(x, s.low, s.high, color=line.get_color(), alpha=0.2, linewidth=0)
        ax.set_title(metric_label(metric), fontsize=9)
        ax.set_xlabel(xlabel)
        if ylabel:
            ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _render(fig, dpi)
