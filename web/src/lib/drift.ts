/**
 * Predicted vs world: when each subgoal was done on each side (the cognition on the predictions and on the
 * true atoms), the drift between them in words, and the events of both sides on one list.
 */
import type { EpisodeEvent, Step, SubgoalState } from "../messages";

export type Side = "predicted" | "world";

type SubgoalSteps = readonly Pick<Step, "t" | "subgoals" | "truth_subgoals">[];

function sideOf(step: Pick<Step, "subgoals" | "truth_subgoals">, side: Side): SubgoalState[] {
  return (side === "predicted" ? step.subgoals : step.truth_subgoals) ?? [];
}

/** Per subgoal index: the step of its latest completion up to step index k (null: not done at k). */
export function doneSteps(steps: SubgoalSteps, k: number, side: Side): Map<number, number | null> {
  const out = new Map<number, number | null>();
  for (let i = 0; i <= Math.min(k, steps.length - 1); i++) {
    const step = steps[i];
    if (!step) continue;
    for (const g of sideOf(step, side)) {
      const was = out.get(g.index) ?? null;
      out.set(g.index, g.status === "done" ? (was ?? step.t) : null);
    }
  }
  return out;
}

export interface SubgoalDrift {
  index: number;
  name: string;
  predicted: number | null;
  world: number | null;
  /** Signed steps predicted minus world (negative: predicted early); null unless both are done. */
  drift: number | null;
  /** One line, e.g. "predicted 24 steps early"; "" when both agree or neither is done. */
  text: string;
}

/** Drift text of one subgoal. */
export function driftText(name: string, predicted: number | null, world: number | null): string {
  if (predicted !== null && world !== null) {
    const d = predicted - world;
    if (d === 0) return "";
    const n = Math.abs(d);
    return `predicted ${name} ${n} step${n === 1 ? "" : "s"} ${d < 0 ? "early" : "late"}`;
  }
  if (predicted !== null) return `predicted ${name} done (step ${predicted}); not done in the world`;
  if (world !== null) return `${name} done in the world (step ${world}); not predicted`;
  return "";
}

/** Every subgoal of the episode with its done step on both sides at step index k. */
export function subgoalDrift(names: readonly { index: number; name: string }[], steps: SubgoalSteps, k: number): SubgoalDrift[] {
  const pred = doneSteps(steps, k, "predicted");
  const world = doneSteps(steps, k, "world");
  return names.map(({ index, name }) => {
    const p = pred.get(index) ?? null;
    const w = world.get(index) ?? null;
    return { index, name, predicted: p, world: w, drift: p !== null && w !== null ? p - w : null, text: driftText(name, p, w) };
  });
}

export interface SidedEvent {
  side: Side;
  event: EpisodeEvent;
}

/** The events of steps 0..k from both sides, newest first (same step: world first, the reference). */
export function mergedEvents(steps: readonly Pick<Step, "events" | "truth_events">[], k: number): SidedEvent[] {
  const out: SidedEvent[] = [];
  for (let i = 0; i <= Math.min(k, steps.length - 1); i++) {
    const step = steps[i];
    for (const e of step?.events ?? []) out.push({ side: "predicted", event: e });
    for (const e of step?.truth_events ?? []) out.push({ side: "world", event: e });
  }
  return out.reverse();
}
