/** The timeline's markers: drops, violations begun, the goal (predicted and world), events, alarms and takeovers. */
import type { Step } from "../messages";
import { alarmText } from "./takeover";

export type MarkerKind =
  | "drop"
  | "violation"
  | "goal-predicted"
  | "goal-world"
  | "event-predicted"
  | "event-world"
  | "alarm"
  | "takeover";

export interface Marker {
  /** Step index (column of the raster). */
  index: number;
  kind: MarkerKind;
  label: string;
}

/** Glyph and words per kind: told apart by shape, never by colour alone. */
export const MARKER_STYLE: Record<MarkerKind, { glyph: string; text: string }> = {
  drop: { glyph: "▼", text: "drop (gripper forced open)" },
  violation: { glyph: "!", text: "violation begins" },
  "goal-predicted": { glyph: "◆", text: "goal reached (predicted)" },
  "goal-world": { glyph: "■", text: "goal reached (world)" },
  "event-predicted": { glyph: "◇", text: "event (predicted)" },
  "event-world": { glyph: "□", text: "event (world)" },
  alarm: { glyph: "⚑", text: "the cognition's alarm" },
  takeover: { glyph: "⇄", text: "handover (to the expert, back to the policy)" },
};

type MarkerStep = Pick<Step, "t" | "violations" | "events" | "truth_events" | "perturbed" | "alarm" | "handover" | "takeover">;

export function markersOf(steps: readonly MarkerStep[]): Marker[] {
  const out: Marker[] = [];
  steps.forEach((s, index) => {
    if (s.perturbed) out.push({ index, kind: "drop", label: `step ${s.t}: gripper forced open` });
    for (const v of s.violations) if (v.since === s.t) out.push({ index, kind: "violation", label: `step ${s.t}: ${v.message}` });
    for (const e of s.events)
      out.push({ index, kind: e.kind === "goal_reached" ? "goal-predicted" : "event-predicted", label: `step ${s.t}, predicted: ${e.message}` });
    for (const e of s.truth_events ?? [])
      out.push({ index, kind: e.kind === "goal_reached" ? "goal-world" : "event-world", label: `step ${s.t}, world: ${e.message}` });
    if (s.alarm) out.push({ index, kind: "alarm", label: `step ${s.t}: alarm, ${alarmText(s.alarm)}` });
    if (s.handover === "to_expert")
      out.push({ index, kind: "takeover", label: `step ${s.t}: the expert takes over (${s.takeover?.reason ?? "?"})` });
    if (s.handover === "to_policy") out.push({ index, kind: "takeover", label: `step ${s.t}: the policy acts again` });
  });
  return out;
}

/** Marker lanes: one per kind, in MARKER_STYLE's order. */
export const MARKER_LANES = Object.keys(MARKER_STYLE) as MarkerKind[];
