/** What the cognition panel shows at a step: active violations, their history, and the events so far. */
import type { EpisodeEvent, Step, Violation } from "../messages";

export interface ViolationSpan {
  violation: Violation;
  /** Step index where it was first seen active. */
  from: number;
  /** Step index where it was last active; null while still active at the shown step. */
  until: number | null;
}

function violationKey(v: Violation): string {
  return `${v.rule}|${v.atoms.join(",")}|${v.since}`;
}

/** Every violation active at some step 0..k, with its span; active ones have `until === null`. */
export function violationHistory(steps: readonly Pick<Step, "violations">[], k: number): ViolationSpan[] {
  const spans = new Map<string, ViolationSpan>();
  for (let i = 0; i <= Math.min(k, steps.length - 1); i++) {
    const active = new Set<string>();
    for (const v of steps[i]?.violations ?? []) {
      const key = violationKey(v);
      active.add(key);
      const span = spans.get(key);
      if (!span || span.until !== null) spans.set(key, { violation: v, from: i, until: null });
    }
    for (const [key, span] of spans) {
      if (span.until === null && !active.has(key)) span.until = i - 1;
    }
  }
  return [...spans.values()];
}

/** The events of steps 0..k, newest first: the cognition's on the predictions, or (`truth`) on the world's atoms. */
export function eventsUntil(
  steps: readonly Pick<Step, "events" | "truth_events">[],
  k: number,
  source: "predicted" | "truth" = "predicted",
): EpisodeEvent[] {
  const out: EpisodeEvent[] = [];
  for (let i = 0; i <= Math.min(k, steps.length - 1); i++) {
    const step = steps[i];
    out.push(...((source === "truth" ? step?.truth_events : step?.events) ?? []));
  }
  return out.reverse();
}
