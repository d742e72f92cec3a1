/**
 * The slider over every step (mouse and keyboard) and the atoms x steps raster beside it: upper half of a
 * cell = predicted, lower half = truth, a red bar where they differ; the slider's step is
 * marked; clicking a cell jumps to its step.
 */
import { useEffect, useMemo, useRef } from "react";
import { type EpisodeData, buildRaster } from "../lib/episode";
import type { EpisodeEnd } from "../messages";
import { HAS_TRUTH, PRED, TRUTH, type RasterLayout, cellAtPoint } from "../lib/raster";
import { stepForKey } from "../lib/slider";

interface Props {
  episode: EpisodeData;
  index: number;
  onSeek: (index: number) => void;
  playing: boolean;
  onPlay: (playing: boolean) => void;
}

const LABEL_WIDTH = 190;
const CELL_H = 10;

export function Timeline({ episode, index, onSeek, playing, onPlay }: Props) {
  const n = episode.steps.length;
  const raster = useMemo(() => buildRaster(episode), [episode, n]);
  const rows = useMemo(() => raster.activeRows(), [raster]);
  const canvas = useRef<HTMLCanvasElement>(null);
  const layout = useMemo<RasterLayout>(() => {
    const width = Math.max(300, Math.min(900, n * 3));
    return { left: LABEL_WIDTH, top: 0, cellWidth: width / Math.max(1, n), cellHeight: CELL_H, rows, numSteps: n };
  }, [rows, n]);

  useEffect(() => {
    const c = canvas.current;
    const ctx = c?.getContext("2d");
    if (!c || !ctx) return;
    const w = layout.left + layout.cellWidth * n;
    const h = Math.max(CELL_H, rows.length * CELL_H);
    const dpr = window.devicePixelRatio || 1;
    c.width = Math.ceil(w * dpr);
    c.height = Math.ceil(h * dpr);
    c.style.width = `${w}px`;
    c.style.height = `${h}px`;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    ctx.font = "9px ui-monospace, monospace";
    ctx.textBaseline = "middle";
    const cw = layout.cellWidth;
    rows.forEach((atom, r) => {
      const y = r * CELL_H;
      ctx.fillStyle = r % 2 ? "#f4f5f7" : "#ffffff";
      ctx.fillRect(0, y, w, CELL_H);
      ctx.fillStyle = "#333";
      ctx.fillText(episode.atoms[atom]?.name ?? "", 2, y + CELL_H / 2, LABEL_WIDTH - 4);
      for (let t = 0; t < n; t++) {
        const code = raster.get(atom, t);
        const x = layout.left + t * cw;
        if (code & PRED) {
          ctx.fillStyle = "#1f5fbf";
          ctx.fillRect(x, y, cw, CELL_H / 2);
        }
        if (code & TRUTH) {
          ctx.fillStyle = "#555";
          ctx.fillRect(x, y + CELL_H / 2, cw, CELL_H / 2);
        }
        if (code & HAS_TRUTH && Boolean(code & PRED) !== Boolean(code & TRUTH)) {
          ctx.fillStyle = "#d62728";
          ctx.fillRect(x, y + CELL_H / 2 - 1, cw, 2);
        }
      }
    });
  }, [raster, rows, layout, n, episode.atoms]);

  const step = episode.steps[index];
  const onCanvasClick = (e: React.MouseEvent<HTMLCanvasElement>) => {
    const rect = e.currentTarget.getBoundingClientRect();
    const cell = cellAtPoint(layout, e.clientX - rect.left, e.clientY - rect.top);
    if (cell) onSeek(cell.step);
  };
  const onKey = (e: React.KeyboardEvent) => {
    const target = stepForKey(e.key, index, n);
    if (target !== null) {
      e.preventDefault();
      onSeek(target);
    }
  };

  return (
    <section className="panel timeline" aria-label="timeline" data-testid="timeline">
      <div className="panel-head">
        <h2>Timeline</h2>
        <button data-testid="play" onClick={() => onPlay(!playing)} disabled={n < 2}>
          {playing ? "❚❚ pause" : "▶ play"}
        </button>
        <input
          data-testid="slider"
          className="slider"
          type="range"
          min={0}
          max={Math.max(0, n - 1)}
          step={1}
          value={index}
          aria-label="step"
          aria-valuetext={`step ${step?.t ?? 0}`}
          onChange={(e) => onSeek(parseInt(e.target.value, 10))}
        />
        <span data-testid="step-indicator" data-t={step?.t ?? ""} data-index={index}>
          step {step?.t ?? "–"} ({index + 1}/{n})
        </span>
      </div>
      {episode.end && <Summary end={episode.end} />}
      <div className="legend muted">
        rows: the {rows.length} of {episode.atoms.length} atoms true at some step · top half, blue: predicted true ·
        bottom half, grey: true in the world · red bar: they differ · orange frame: shown step · click a cell to
        jump there (arrow keys move)
      </div>
      <div className="raster-wrap">
        <div
          className="raster-marker"
          data-testid="raster-marker"
          style={{
            left: layout.left + index * layout.cellWidth,
            width: Math.max(2, layout.cellWidth),
            height: Math.max(CELL_H, rows.length * CELL_H),
          }}
        />
        <canvas
          ref={canvas}
          data-testid="raster"
          tabIndex={0}
          onClick={onCanvasClick}
          onKeyDown={onKey}
          aria-label="atoms by steps raster"
          data-left={layout.left}
          data-cell-width={layout.cellWidth}
          data-cell-height={layout.cellHeight}
          data-rows={rows.length}
        />
      </div>
    </section>
  );
}

/** How the episode went as a whole (the server's episode_end summary). */
function Summary({ end }: { end: EpisodeEnd }) {
  const s = end.summary;
  const rules = Object.entries(s.violations).sort((a, b) => (b[1] ?? 0) - (a[1] ?? 0));
  return (
    <div className="summary" data-testid="summary">
      <strong>{end.success ? "✓ success" : end.stopped ? "■ stopped" : "✗ failed"}</strong> · {end.steps} steps ·
      agreement {(100 * s.agreement).toFixed(1)} % · goal reached at step {s.goal_step_predicted ?? "–"} (predicted)
      / {s.goal_step_truth ?? "–"} (world) · violations:{" "}
      {rules.length === 0 ? "none" : rules.map(([rule, count]) => `${rule} ×${count}`).join(", ")}
    </div>
  );
}
