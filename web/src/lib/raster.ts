/**
 * The atoms x steps raster of an episode: one byte per cell (predicted, truth, whether truth is known),
 * rows limited to the atoms that are true at some step, and the mapping from a click to (atom, step).
 */

export const PRED = 1;
export const TRUTH = 2;
export const HAS_TRUTH = 4;

export class Raster {
  readonly cells: Uint8Array;

  constructor(
    readonly numAtoms: number,
    readonly numSteps: number,
  ) {
    this.cells = new Uint8Array(numAtoms * numSteps);
  }

  /** Index of the cell of `atom` at `step` (row-major by atom). */
  index(atom: number, step: number): number {
    return atom * this.numSteps + step;
  }

  get(atom: number, step: number): number {
    return this.cells[this.index(atom, step)] ?? 0;
  }

  /** Fills column `step` from the step's predicted and (optional) true values. */
  setStep(step: number, predicted: readonly number[], truth: readonly number[] | null): void {
    for (let a = 0; a < this.numAtoms; a++) {
      let code = predicted[a] ? PRED : 0;
      if (truth) code |= HAS_TRUTH | (truth[a] ? TRUTH : 0);
      this.cells[this.index(a, step)] = code;
    }
  }

  /** Atoms predicted or truly true at some step, in vector order: the rows worth drawing. */
  activeRows(): number[] {
    const rows: number[] = [];
    for (let a = 0; a < this.numAtoms; a++) {
      for (let t = 0; t < this.numSteps; t++) {
        if ((this.cells[this.index(a, t)] ?? 0) & (PRED | TRUTH)) {
          rows.push(a);
          break;
        }
      }
    }
    return rows;
  }
}

export type CellKind = "on" | "off" | "missed" | "false-alarm";

/** Classifies a cell: true/false where prediction and truth agree (or no truth), else the kind of error. */
export function cellKind(code: number): CellKind {
  const pred = (code & PRED) !== 0;
  if (code & HAS_TRUTH) {
    const truth = (code & TRUTH) !== 0;
    if (pred && !truth) return "false-alarm";
    if (!pred && truth) return "missed";
  }
  return pred ? "on" : "off";
}

export interface RasterLayout {
  /** Left edge of the cells (room for labels), in CSS pixels. */
  left: number;
  top: number;
  cellWidth: number;
  cellHeight: number;
  rows: readonly number[];
  numSteps: number;
}

/** The (atom, step) under a point of the raster canvas, or null outside the cells. */
export function cellAtPoint(layout: RasterLayout, x: number, y: number): { atom: number; step: number } | null {
  const col = Math.floor((x - layout.left) / layout.cellWidth);
  const row = Math.floor((y - layout.top) / layout.cellHeight);
  if (x < layout.left || y < layout.top || col >= layout.numSteps || row >= layout.rows.length) return null;
  const atom = layout.rows[row];
  return atom === undefined ? null : { atom, step: col };
}

/** Steps between two labelled ticks of the step axis, so labels stay at least `minPx` apart. */
export function tickEvery(cellWidth: number, minPx = 48): number {
  for (const every of [1, 2, 5, 10, 20, 25, 50, 100, 200, 500, 1000]) if (every * cellWidth >= minPx) return every;
  return 1000;
}

/** The column (step index) under x in the cells canvas, or null outside. */
export function stepAtX(cellWidth: number, numSteps: number, x: number): number | null {
  const col = Math.floor(x / cellWidth);
  return x < 0 || col >= numSteps ? null : col;
}
