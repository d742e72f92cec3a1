/**
 * Drawing the timeline raster on canvases: marker lanes and a step axis on top, then one row per atom. A cell's
 * top band is the prediction (solid), its bottom band the world (hatched), and a cell where they differ is
 * tinted with a dark bar between the bands: shape and pattern tell them apart, not colour alone.
 */
import { HAS_TRUTH, PRED, type Raster, TRUTH, tickEvery } from "./raster";
import { MARKER_LANES, MARKER_STYLE, type Marker } from "./markers";

export const ROW_H = 14;
export const LANE_H = 13;
export const AXIS_H = 18;
export const HEADER_H = MARKER_LANES.length * LANE_H + AXIS_H;
export const LABEL_W = 290;

const INK = "#1d2230";
const PRED_FILL = "#1f4fa0";
const DIFFER_TINT = "#f7c8cc";
const DIFFER_BAR = "#7a0010";

export interface Canvas2D {
  canvas: HTMLCanvasElement;
  ctx: CanvasRenderingContext2D;
}

/** Sizes a canvas for the device pixel ratio and returns its context in CSS pixels. */
export function prepare(canvas: HTMLCanvasElement | null, w: number, h: number): CanvasRenderingContext2D | null {
  const ctx = canvas?.getContext("2d");
  if (!canvas || !ctx) return null;
  const dpr = window.devicePixelRatio || 1;
  canvas.width = Math.ceil(w * dpr);
  canvas.height = Math.ceil(h * dpr);
  canvas.style.width = `${w}px`;
  canvas.style.height = `${h}px`;
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, w, h);
  return ctx;
}

function hatch(ctx: CanvasRenderingContext2D): CanvasPattern | string {
  const tile = document.createElement("canvas");
  tile.width = tile.height = 4;
  const t = tile.getContext("2d");
  if (!t) return "#555";
  t.fillStyle = "#b9bdc7";
  t.fillRect(0, 0, 4, 4);
  t.strokeStyle = "#2b2f3a";
  t.lineWidth = 1.2;
  t.beginPath();
  t.moveTo(0, 4);
  t.lineTo(4, 0);
  t.stroke();
  return ctx.createPattern(tile, "repeat") ?? "#555";
}

/** Row labels and lane names (the left canvas, kept in view while panning). */
export function drawLabels(ctx: CanvasRenderingContext2D, names: readonly string[], pinned: number): void {
  ctx.fillStyle = "#fff";
  ctx.fillRect(0, 0, LABEL_W, HEADER_H + names.length * ROW_H);
  ctx.textBaseline = "middle";
  ctx.font = "11px system-ui, sans-serif";
  ctx.fillStyle = INK;
  MARKER_LANES.forEach((kind, i) => {
    const s = MARKER_STYLE[kind];
    ctx.fillText(`${s.glyph} ${s.text}`, 4, i * LANE_H + LANE_H / 2, LABEL_W - 8);
  });
  ctx.fillText("step", 4, HEADER_H - AXIS_H / 2);
  ctx.font = "12px ui-monospace, monospace";
  names.forEach((name, r) => {
    const y = HEADER_H + r * ROW_H;
    ctx.fillStyle = r % 2 ? "#f1f3f7" : "#fff";
    ctx.fillRect(0, y, LABEL_W, ROW_H);
    ctx.fillStyle = INK;
    ctx.font = r < pinned ? "bold 11px ui-monospace, monospace" : "11px ui-monospace, monospace";
    ctx.fillText(fit(ctx, name, LABEL_W - 8), 4, y + ROW_H / 2);
  });
  separator(ctx, pinned, LABEL_W);
}

/** The text cut with an ellipsis to fit `width` (never squeezed: squeezed glyphs are unreadable). */
function fit(ctx: CanvasRenderingContext2D, text: string, width: number): string {
  if (ctx.measureText(text).width <= width) return text;
  let lo = 0;
  let hi = text.length;
  while (lo < hi) {
    const mid = Math.ceil((lo + hi) / 2);
    if (ctx.measureText(`${text.slice(0, mid)}…`).width <= width) lo = mid;
    else hi = mid - 1;
  }
  return `${text.slice(0, lo)}…`;
}

function separator(ctx: CanvasRenderingContext2D, pinned: number, w: number): void {
  ctx.fillStyle = INK;
  ctx.fillRect(0, HEADER_H - 1, w, 1);
  if (pinned > 0) ctx.fillRect(0, HEADER_H + pinned * ROW_H - 1, w, 2);
}

/** What the cells canvas shows; columns `from`..numSteps-1 are (re)drawn (0: the whole canvas). */
export interface CellsView {
  raster: Raster;
  rows: readonly number[];
  pinned: number;
  cw: number;
  stepT: (index: number) => number;
  markers: readonly Marker[];
  from: number;
}

/** Marker lanes, the step axis, and the cells of columns `from` onwards (a live episode adds a column a step). */
export function drawCells(ctx: CanvasRenderingContext2D, v: CellsView): void {
  const n = v.raster.numSteps;
  const x0 = v.from * v.cw;
  const w = (n - v.from) * v.cw;
  ctx.clearRect(x0, 0, w, HEADER_H + v.rows.length * ROW_H);
  drawMarkers(ctx, v.markers.filter((m) => m.index >= v.from), v.cw);
  drawAxis(ctx, v.from, n, v.cw, v.stepT);
  const truthFill = hatch(ctx);
  v.rows.forEach((atom, r) => {
    const y = HEADER_H + r * ROW_H;
    ctx.fillStyle = r % 2 ? "#f1f3f7" : "#fff";
    ctx.fillRect(x0, y, w, ROW_H);
    for (let t = v.from; t < n; t++) drawCell(ctx, v.raster.get(atom, t), t * v.cw, y, v.cw, truthFill);
  });
  ctx.fillStyle = INK;
  ctx.fillRect(x0, HEADER_H - 1, w, 1);
  if (v.pinned > 0) ctx.fillRect(x0, HEADER_H + v.pinned * ROW_H - 1, w, 2);
}

function drawCell(ctx: CanvasRenderingContext2D, code: number, x: number, y: number, cw: number, truthFill: CanvasPattern | string): void {
  const pred = (code & PRED) !== 0;
  const truth = (code & TRUTH) !== 0;
  const differ = (code & HAS_TRUTH) !== 0 && pred !== truth;
  if (differ) {
    ctx.fillStyle = DIFFER_TINT;
    ctx.fillRect(x, y, cw, ROW_H);
  }
  if (pred) {
    ctx.fillStyle = PRED_FILL;
    ctx.fillRect(x, y + 1, cw, 5);
  }
  if (truth) {
    ctx.fillStyle = truthFill;
    ctx.fillRect(x, y + 8, cw, 5);
  }
  if (differ) {
    ctx.fillStyle = DIFFER_BAR;
    ctx.fillRect(x, y + 6, cw, 2);
  }
}

function drawAxis(ctx: CanvasRenderingContext2D, from: number, n: number, cw: number, stepT: (index: number) => number): void {
  const y0 = HEADER_H - AXIS_H;
  const every = tickEvery(cw);
  ctx.fillStyle = INK;
  ctx.font = "11px system-ui, sans-serif";
  ctx.textBaseline = "middle";
  for (let i = from; i < n; i++) {
    const t = stepT(i);
    if (t % every !== 0) continue;
    const x = i * cw;
    ctx.fillRect(x, y0 + AXIS_H - 6, 1, 5);
    ctx.fillText(String(t), x + 2, y0 + AXIS_H / 2 - 2);
  }
}

function drawMarkers(ctx: CanvasRenderingContext2D, markers: readonly Marker[], cw: number): void {
  ctx.font = "11px system-ui, sans-serif";
  ctx.textBaseline = "middle";
  ctx.textAlign = "center";
  ctx.fillStyle = INK;
  for (const m of markers) {
    const lane = MARKER_LANES.indexOf(m.kind);
    ctx.fillText(MARKER_STYLE[m.kind].glyph, m.index * cw + cw / 2, lane * LANE_H + LANE_H / 2);
  }
  ctx.textAlign = "start";
}
