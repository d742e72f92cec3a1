/**
 * Flip and fade: an atom that just turned true is shown as "turned-on" (green), one that just turned false
 * as "turned-off" (red), and the highlight fades out over `fadeSteps` steps (the paper's belief panel).
 */

export type AtomState = "on" | "off" | "turned-on" | "turned-off";

export interface AtomView {
  value: number;
  state: AtomState;
  /** Steps since the atom last changed (0 = changed at this step); Infinity when it did not change in the window. */
  age: number;
  /** Highlight strength in [0, 1]: 1 at the flip, 0 once `fadeSteps` steps have passed. */
  fade: number;
}

export const DEFAULT_FADE_STEPS = 5;

/**
 * The state of every atom at step `k`, from the value vectors of steps 0..k (`bitsAt(j)`). Looks back at
 * most `fadeSteps` steps, so the cost per step does not grow with the episode.
 */
export function atomViewsAt(
  bitsAt: (j: number) => readonly number[],
  k: number,
  fadeSteps: number = DEFAULT_FADE_STEPS,
): AtomView[] {
  const current = bitsAt(k);
  const ages = new Array<number>(current.length).fill(Infinity);
  let later = current;
  for (let j = k - 1; j >= Math.max(0, k - fadeSteps); j--) {
    const earlier = bitsAt(j);
    const age = k - j - 1;
    for (let i = 0; i < current.length; i++) {
      if (ages[i] === Infinity && (earlier[i] ?? 0) !== (later[i] ?? 0)) ages[i] = age;
    }
    later = earlier;
  }
  return current.map((value, i) => viewOf(value, ages[i] ?? Infinity, fadeSteps));
}

function viewOf(value: number, age: number, fadeSteps: number): AtomView {
  const fresh = age < fadeSteps;
  const state: AtomState = fresh ? (value ? "turned-on" : "turned-off") : value ? "on" : "off";
  const fade = fresh ? 1 - age / fadeSteps : 0;
  return { value, state, age, fade };
}

export type BeliefFilter = "all" | "true" | "changed";

/** Whether an atom passes the belief panel's filter ("changed" = changed at this very step). */
export function passesFilter(view: AtomView, filter: BeliefFilter): boolean {
  if (filter === "true") return view.value === 1;
  if (filter === "changed") return view.age === 0;
  return true;
}
