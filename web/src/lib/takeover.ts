/**
 * Who acts at a step (`serve --takeover`): the policy, or the scripted expert during a takeover; the cognition's
 * alarms so far with their reason, rules and atoms; and one line for the shown step.
 */
import type { Alarm, Step, Takeover } from "../messages";

type TakeoverStep = Pick<Step, "t" | "alarm" | "takeover" | "handover">;

export interface AlarmAt {
  /** Step index where the alarm fired (the expert acts from the next step). */
  index: number;
  t: number;
  alarm: Alarm;
}

export interface Acting {
  /** "expert": the scripted expert executed this step's action in a takeover; else the episode's driver. */
  who: "expert" | "policy";
  takeover: Takeover | null;
}

/** Who executed the action of a step (null: no step). */
export function actingAt(steps: readonly TakeoverStep[], k: number): Acting | null {
  const step = steps[k];
  if (!step) return null;
  const takeover = step.takeover ?? null;
  return { who: takeover ? "expert" : "policy", takeover };
}

/** The alarms of steps 0..k, newest first. */
export function alarmsUntil(steps: readonly TakeoverStep[], k: number): AlarmAt[] {
  const out: AlarmAt[] = [];
  for (let i = 0; i <= Math.min(k, steps.length - 1); i++) {
    const alarm = steps[i]?.alarm;
    if (alarm) out.push({ index: i, t: steps[i]!.t, alarm });
  }
  return out.reverse();
}

/** The takeovers begun at steps 0..k, each as of the latest of those steps under it (oldest first). */
export function takeoversUntil(steps: readonly TakeoverStep[], k: number): Takeover[] {
  const byIndex = new Map<number, Takeover>();
  for (let i = 0; i <= Math.min(k, steps.length - 1); i++) {
    const t = steps[i]?.takeover;
    if (t) byIndex.set(t.index, t);
  }
  return [...byIndex.values()].sort((a, b) => a.index - b.index);
}

/** The alarm's reason in words, with the rules and atoms that drove it. */
export function alarmText(alarm: Alarm): string {
  const parts = [`${alarm.kind}: ${alarm.reason}`];
  if (alarm.rules.length > 0) parts.push(`rules ${alarm.rules.join(", ")}`);
  if (alarm.atoms.length > 0) parts.push(`atoms ${alarm.atoms.join(", ")}`);
  return parts.join(" · ");
}

/**
 * One line for the shown step: who acts, and in a takeover which one, since when and why. `length`: the
 * server's --takeover-steps, the cap of a takeover under `until` "subgoal" (it hands back once its subgoal is done).
 */
export function actingText(acting: Acting, length: number | null, until: "subgoal" | "steps" = "steps"): string {
  const t = acting.takeover;
  if (!t) return "the policy acts";
  const of = !length ? "" : until === "subgoal" ? ` of at most ${length}, until its subgoal is done,` : ` of ${length}`;
  return `the scripted expert acts: takeover ${t.index}, action ${t.steps}${of} since step ${t.start} (${t.reason})`;
}
