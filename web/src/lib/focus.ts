/**
 * The focused beliefs view: which atoms matter for the task (pinned), and the rows one step shows, filtered
 * and sorted so that what the probes get wrong comes first. Pure functions over an episode's bit vectors.
 */
import type { AtomInfo } from "./atoms";
import type { AtomState } from "./flips";

/** The arguments of an atom name: `on(a,b)` -> [a, b]. */
export function argsOf(atom: string): string[] {
  const open = atom.indexOf("(");
  const close = atom.lastIndexOf(")");
  if (open < 0 || close < open) return [];
  return atom
    .slice(open + 1, close)
    .split(",")
    .map((s) => s.trim())
    .filter(Boolean);
}

/** The noun of an object name: `akita_black_bowl_1` -> `bowl` (numbers and the maker's prefix dropped). */
function nounOf(object: string): string {
  const words = object.split("_").filter((w) => !/^\d+$/.test(w));
  return words[words.length - 1] ?? object;
}

/**
 * The task's objects: the server's `goal_objects` when sent, else (older recordings) every object whose
 * noun appears in the instruction.
 */
export function taskObjects(goalObjects: readonly string[] | undefined, instruction: string, atoms: readonly AtomInfo[]): Set<string> {
  if (goalObjects && goalObjects.length > 0) return new Set(goalObjects);
  const words = new Set(instruction.toLowerCase().split(/[^a-z]+/));
  const out = new Set<string>();
  for (const a of atoms) for (const o of argsOf(a.name)) if (words.has(nounOf(o).toLowerCase())) out.add(o);
  return out;
}

/** Pinned: every action atom, and every atom that mentions one of the task's objects. */
export function isPinned(atom: AtomInfo, objects: ReadonlySet<string>): boolean {
  return atom.head === "action" || argsOf(atom.name).some((o) => objects.has(o));
}

/** One belief row at the shown step. */
export interface BeliefRow {
  index: number;
  name: string;
  pinned: boolean;
  probed: boolean;
  /** Predicted value and its state (flip and fade). */
  value: number;
  state: AtomState;
  /** Steps since the prediction changed (Infinity: not within the window). */
  age: number;
  /** The world's value; null without truth. */
  truth: number | null;
  /** Steps since the world's value changed (Infinity: not within the window or no truth). */
  worldAge: number;
  /** Probed and the world differs. */
  disagree: boolean;
  prob: number | null;
}

export type RowFilter = "all" | "disagree" | "changed" | "true";

export interface RowOptions {
  filter: RowFilter;
  /** Show atoms without a probe (held at their training majority, never flipping). */
  showUnprobed: boolean;
  /** Steps within which a change counts as "changed" (the fade window). */
  window: number;
}

/** Whether a row changed within the window, on the predicted side or in the world. */
export function changed(row: BeliefRow, window: number): boolean {
  return row.age < window || row.worldAge < window;
}

export function passes(row: BeliefRow, opts: RowOptions): boolean {
  if (!row.probed && !opts.showUnprobed) return false;
  if (opts.filter === "disagree") return row.disagree;
  if (opts.filter === "changed") return changed(row, opts.window);
  if (opts.filter === "true") return row.value === 1;
  return true;
}

/**
 * Disagreements first, then the vector order. Deliberately not by recency: a list that reorders at the stream's
 * rate cannot be read (recent changes are marked, and the "changed" filter selects them).
 */
export function compareRows(a: BeliefRow, b: BeliefRow): number {
  if (a.disagree !== b.disagree) return a.disagree ? -1 : 1;
  return a.index - b.index;
}

export interface Sections {
  pinned: BeliefRow[];
  other: BeliefRow[];
  /** Rows hidden only because they are not probed. */
  hiddenUnprobed: number;
}

/** The focused view: pinned rows, then the others, each filtered and sorted. */
export function focusedSections(rows: readonly BeliefRow[], opts: RowOptions): Sections {
  const shown = rows.filter((r) => passes(r, opts)).sort(compareRows);
  const hiddenUnprobed = opts.showUnprobed ? 0 : rows.filter((r) => !r.probed && passes(r, { ...opts, showUnprobed: true })).length;
  return { pinned: shown.filter((r) => r.pinned), other: shown.filter((r) => !r.pinned), hiddenUnprobed };
}

/** Steps since each value last changed, looking back at most `window` steps (Infinity: no change). */
export function agesAt(bitsAt: (j: number) => readonly number[] | null, k: number, window: number): number[] {
  const current = bitsAt(k);
  if (!current) return [];
  const ages = new Array<number>(current.length).fill(Infinity);
  let later = current;
  for (let j = k - 1; j >= Math.max(0, k - window); j--) {
    const earlier = bitsAt(j);
    if (!earlier) break;
    for (let i = 0; i < current.length; i++) {
      if (ages[i] === Infinity && (earlier[i] ?? 0) !== (later[i] ?? 0)) ages[i] = k - j - 1;
    }
    later = earlier;
  }
  return ages;
}

/**
 * The timeline's rows: the task-relevant atoms first (every action atom, and pinned atoms once true), then the others
 * true at some step. Atoms the episode leaves undefined (`episode_start.defined`) are left out, as in the belief list:
 * their 0s are placeholders, not "false".
 */
export function timelineRows(active: readonly number[], atoms: readonly AtomInfo[], objects: ReadonlySet<string>): { rows: number[]; pinned: number } {
  const defined = new Set(atoms.filter((a) => a.defined).map((a) => a.index));
  const isActive = new Set(active);
  const first = atoms
    .filter((a) => a.defined && isPinned(a, objects) && (a.head === "action" || isActive.has(a.index)))
    .map((a) => a.index);
  const pinnedSet = new Set(first);
  return { rows: [...first, ...active.filter((i) => defined.has(i) && !pinnedSet.has(i))], pinned: first.length };
}
