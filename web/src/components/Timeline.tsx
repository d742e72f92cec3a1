/**
 * The timeline: a slider over every step (also while the episode runs: scrub back, then "back to live"), and
 * the atoms x steps raster with marker lanes (drop, violations, goal predicted and world, events), a step axis,
 * the task-relevant rows first, and zoom (the raster pans by scrolling). Clicking a cell jumps to its step.
 */
import { useEffect, useMemo, useRef, useState } from "react";
import { episodeObjects } from "../lib/beliefRows";
import { type EpisodeData, buildRaster } from "../lib/episode";
import { timelineRows } from "../lib/focus";
import { MARKER_LANES, MARKER_STYLE, markersOf } from "../lib/markers";
import { stepAtX, tickEvery } from "../lib/raster";
import { type CellsView, HEADER_H, LABEL_W, ROW_H, drawCells, drawLabels, prepare } from "../lib/rasterDraw";
import { stepForKey } from "../lib/slider";
import { endWord, stepsPhrase } from "../lib/status";
import { useThrottled } from "../useThrottled";
import type { EpisodeEnd } from "../messages";

interface Props {
  episode: EpisodeData;
  index: number;
  onSeek: (index: number) => void;
  playing: boolean;
  onPlay: (playing: boolean) => void;
  /** The episode is streaming now. */
  live: boolean;
  following: boolean;
  onBackToLive: () => void;
}

const ZOOMS = [1, 2, 4, 8, 16];

/** Pixels per step: "fit" fills the visible width with the episode's budget (at least 1, at most 8). */
function cellWidth(zoom: number | "fit", steps: number, visible: number): number {
  if (zoom !== "fit") return zoom;
  return Math.max(1, Math.min(8, Math.floor((visible / Math.max(1, steps)) * 4) / 4));
}

function useVisibleWidth(ref: React.RefObject<HTMLDivElement | null>): number {
  const [width, setWidth] = useState(700);
  useEffect(() => {
    const el = ref.current;
    if (!el) return;
    const measure = () => setWidth(Math.max(200, el.clientWidth - LABEL_W - 4));
    measure();
    const obs = new ResizeObserver(measure);
    obs.observe(el);
    return () => obs.disconnect();
  }, [ref]);
  return width;
}

function Zoom({ zoom, setZoom, cw }: { zoom: number | "fit"; setZoom: (z: number | "fit") => void; cw: number }) {
  const smaller = [...ZOOMS].reverse().find((z) => z < cw) ?? ZOOMS[0] ?? 1;
  const larger = ZOOMS.find((z) => z > cw) ?? ZOOMS[ZOOMS.length - 1] ?? 16;
  return (
    <span className="zoom" role="group" aria-label="zoom">
      <button onClick={() => setZoom(smaller)} aria-label="zoom out" data-testid="zoom-out">
        −
      </button>
      <button onClick={() => setZoom("fit")} aria-pressed={zoom === "fit"} data-testid="zoom-fit">
        fit
      </button>
      <button onClick={() => setZoom(larger)} aria-label="zoom in" data-testid="zoom-in">
        +
      </button>
      <span className="muted">{cw} px/step</span>
    </span>
  );
}

function Legend({ rows, total, pinned, left }: { rows: number; total: number; pinned: number; left: number }) {
  return (
    <div className="legend raster-legend">
      <span>
        <i className="sw pred" /> predicted true (solid, top)
      </span>
      <span>
        <i className="sw truth" /> true in the world (hatched, bottom)
      </span>
      <span>
        <i className="sw differ" /> they differ (tinted, dark middle bar)
      </span>
      <span>
        markers: {MARKER_LANES.map((k) => `${MARKER_STYLE[k].glyph} ${MARKER_STYLE[k].text}`).join(" · ")}
      </span>
      <span>
        rows: {pinned} task-relevant (bold, on top), then the others true at some step: {rows} of {total} atoms · click a
        cell to jump there
      </span>
      {left > 0 && <span data-testid="raster-undefined">{left} atoms undefined in this task (objects it lacks): not drawn</span>}
    </div>
  );
}

interface RasterProps {
  episode: EpisodeData;
  index: number;
  onSeek: (i: number) => void;
  zoom: number | "fit";
  setZoom: (z: number | "fit") => void;
}

/**
 * The cells canvas is as wide as the episode's step budget, so a live episode only adds columns: each step
 * draws its new column (from the last axis tick on); rows, zoom or size changing redraw it whole.
 */
function useCellsCanvas(canvas: React.RefObject<HTMLCanvasElement | null>, view: Omit<CellsView, "from">, width: number, height: number) {
  const drawn = useRef({ key: "", n: 0 });
  const n = view.raster.numSteps;
  useEffect(() => {
    const key = `${view.rows.join(",")}|${view.pinned}|${view.cw}|${width}|${height}`;
    let from = 0;
    let ctx: CanvasRenderingContext2D | null | undefined;
    if (key === drawn.current.key && n >= drawn.current.n) {
      const every = tickEvery(view.cw);
      from = Math.max(0, Math.floor((drawn.current.n - 1) / every) * every);
      ctx = canvas.current?.getContext("2d");
    } else ctx = prepare(canvas.current, width, height);
    if (ctx) drawCells(ctx, { ...view, from });
    drawn.current = { key, n };
  }, [canvas, view, n, width, height]);
}

function Raster({ episode, index, onSeek, zoom, setZoom }: RasterProps) {
  const n = useThrottled(episode.steps.length, episode.end ? 0 : 500);
  const wrap = useRef<HTMLDivElement>(null);
  const labels = useRef<HTMLCanvasElement>(null);
  const cells = useRef<HTMLCanvasElement>(null);
  const visible = useVisibleWidth(wrap);
  const budget = Math.max(episode.steps.length, episode.end ? 0 : episode.start.max_steps);
  const cw = cellWidth(zoom, budget, visible);
  const objects = useMemo(() => episodeObjects(episode), [episode]);
  const raster = useMemo(() => buildRaster(episode, n), [episode, n]); // steps are appended in place: n marks a change
  const active = useMemo(() => raster.activeRows(), [raster]);
  const activeKey = active.join(",");
  const { rows, pinned } = useMemo(() => timelineRows(active, episode.atoms, objects), [activeKey, episode.atoms, objects]); // new rows only
  const markers = useMemo(() => markersOf(episode.steps.slice(0, n)), [episode, n]);
  const defined = useMemo(() => episode.atoms.filter((a) => a.defined).length, [episode.atoms]);
  const height = HEADER_H + rows.length * ROW_H;
  const view = useMemo(
    () => ({ raster, rows, pinned, cw, markers, stepT: (i: number) => episode.steps[i]?.t ?? i }),
    [raster, rows, pinned, cw, markers, episode],
  );
  useEffect(() => {
    const ctx = prepare(labels.current, LABEL_W, height);
    if (ctx) drawLabels(ctx, rows.map((a) => episode.atoms[a]?.name ?? ""), pinned);
  }, [rows, pinned, height, episode.atoms]);
  useCellsCanvas(cells, view, Math.max(1, budget * cw), height);
  useEffect(() => {
    const el = wrap.current;
    if (!el) return;
    const x = index * cw;
    const view = el.clientWidth - LABEL_W;
    if (x < el.scrollLeft || x > el.scrollLeft + view - cw) el.scrollLeft = Math.max(0, x - view / 2);
  }, [index, cw]);
  const onClick = (e: React.MouseEvent<HTMLCanvasElement>) => {
    const step = stepAtX(cw, episode.steps.length, e.clientX - e.currentTarget.getBoundingClientRect().left);
    if (step !== null) onSeek(step);
  };
  return (
    <>
      <div className="raster-tools">
        <Zoom zoom={zoom} setZoom={setZoom} cw={cw} />
        <Legend rows={rows.length} total={defined} pinned={pinned} left={episode.atoms.length - defined} />
      </div>
      <div className="raster-wrap" ref={wrap}>
        <canvas ref={labels} className="labels" aria-hidden="true" />
        <div className="cells">
          <div className="raster-marker" data-testid="raster-marker" style={{ left: index * cw, width: Math.max(3, cw), height }} />
          <canvas
            ref={cells}
            data-testid="raster"
            onClick={onClick}
            role="img"
            aria-label={`atoms by steps raster: ${rows.length} rows, ${n} steps; use the slider to move`}
            data-left={0}
            data-top={HEADER_H}
            data-cell-width={cw}
            data-cell-height={ROW_H}
            data-rows={rows.length}
            data-pinned={pinned}
          />
        </div>
      </div>
    </>
  );
}

export function Timeline({ episode, index, onSeek, playing, onPlay, live, following, onBackToLive }: Props) {
  const n = episode.steps.length;
  const [zoom, setZoom] = useState<number | "fit">("fit");
  const step = episode.steps[index];
  const onKey = (e: React.KeyboardEvent) => {
    const target = stepForKey(e.key, index, n);
    if (target !== null) {
      e.preventDefault();
      onSeek(target);
    }
  };
  return (
    <section className="panel timeline" aria-labelledby="timeline-h" data-testid="timeline" id="timeline" tabIndex={-1}>
      <div className="panel-head">
        <h2 id="timeline-h">Timeline</h2>
        <button data-testid="play" onClick={() => onPlay(!playing)} disabled={n < 2 || live}>
          {playing ? "❚❚ pause" : "▶ play"}
        </button>
        <input
          data-testid="slider"
          id="timeline-slider"
          className="slider"
          type="range"
          min={0}
          max={Math.max(0, n - 1)}
          step={1}
          value={index}
          aria-label="step"
          aria-valuetext={`step ${step?.t ?? 0}`}
          onKeyDown={onKey}
          onChange={(e) => onSeek(parseInt(e.target.value, 10))}
        />
        <span data-testid="step-indicator" data-t={step?.t ?? ""} data-index={index} data-following={following ? "1" : "0"}>
          step {step?.t ?? "–"} ({index + 1}/{n})
        </span>
        {live &&
          (following ? (
            <span className="live-tag">● following live</span>
          ) : (
            <button data-testid="follow-live" onClick={onBackToLive} className="primary">
              ⏭ back to live
            </button>
          ))}
      </div>
      {episode.end && <Summary end={episode.end} />}
      <Raster episode={episode} index={index} onSeek={onSeek} zoom={zoom} setZoom={setZoom} />
    </section>
  );
}

/** How the episode went as a whole (the server's episode_end summary). */
function Summary({ end }: { end: EpisodeEnd }) {
  const s = end.summary;
  const rules = Object.entries(s.violations).sort((a, b) => (b[1] ?? 0) - (a[1] ?? 0));
  return (
    <div className="summary" data-testid="summary">
      <strong>{endWord(end)}</strong> · {stepsPhrase(end)} · agreement {(100 * s.agreement).toFixed(1)} % · goal reached at
      step {s.goal_step_predicted ?? "–"} (predicted) / {s.goal_step_truth ?? "–"} (world) · violations:{" "}
      {rules.length === 0 ? "none" : rules.map(([rule, count]) => `${rule} ×${count}`).join(", ")}
    </div>
  );
}
