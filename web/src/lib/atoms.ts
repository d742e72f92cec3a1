/** Atom names and bit vectors of an episode: object head first, then action head (the paper's order). */
import type { EpisodeStart, Step } from "../messages";

export type Head = "object" | "action";

export interface AtomInfo {
  /** Position in the concatenated object+action vector. */
  index: number;
  name: string;
  head: Head;
  /** Predicate name, e.g. `left-of` for `left-of(bowl,plate)`. */
  predicate: string;
  probed: boolean;
  /** False: undefined in this episode (an object absent from the task; `episode_start.defined`). */
  defined: boolean;
}

export function predicateOf(atom: string): string {
  const i = atom.indexOf("(");
  return i < 0 ? atom : atom.slice(0, i);
}

/** Every atom of the episode in vector order. */
export function atomInfos(start: Pick<EpisodeStart, "atoms" | "probed" | "defined">): AtomInfo[] {
  const out: AtomInfo[] = [];
  for (const head of ["object", "action"] as const) {
    const names = start.atoms[head];
    const probed = start.probed[head];
    const defined = start.defined?.[head];
    names.forEach((name, i) => {
      const info = { index: out.length, name, head, predicate: predicateOf(name), probed: probed[i] ?? false };
      out.push({ ...info, defined: defined?.[i] ?? true });
    });
  }
  return out;
}

export interface PredicateGroup {
  head: Head;
  predicate: string;
  atoms: AtomInfo[];
}

/** Atoms grouped by predicate, groups in first-appearance order (object predicates before action ones). */
export function groupByPredicate(atoms: AtomInfo[]): PredicateGroup[] {
  const groups = new Map<string, PredicateGroup>();
  for (const a of atoms) {
    const key = `${a.head}:${a.predicate}`;
    let g = groups.get(key);
    if (!g) {
      g = { head: a.head, predicate: a.predicate, atoms: [] };
      groups.set(key, g);
    }
    g.atoms.push(a);
  }
  return [...groups.values()];
}

/** The step's predicted values, object then action. */
export function predictedBits(step: Pick<Step, "predicted">): number[] {
  return [...step.predicted.object.values, ...step.predicted.action.values];
}

/** The step's true values, object then action; null when the server streams no truth. */
export function truthBits(step: Pick<Step, "truth">): number[] | null {
  return step.truth ? [...step.truth.object, ...step.truth.action] : null;
}
