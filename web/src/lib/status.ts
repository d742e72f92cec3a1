/**
 * What the page says about the episode: the stream type (live, recorded, store re-run), the caption with the
 * step counts, the summary line, the per-step timings, the drop indicator, and the driver a start asks for.
 */
import type { EpisodeEnd, Step } from "../messages";
import type { EpisodeData } from "./episode";

export type StreamKind = "live" | "recorded" | "store re-run" | "stored";

/** A live stream from the simulator or a store re-run (streamed), or an episode opened from the list. */
export function streamKind(episode: EpisodeData, opened: boolean): StreamKind {
  const store = episode.start.source === "store";
  if (opened) return store ? "stored" : "recorded";
  return store ? "store re-run" : "live";
}

/** The episode's step at which the task's own success check first held (null: none so far). */
export function successStep(episode: EpisodeData): number | null {
  const fromEnd = episode.end?.summary.success_step;
  if (fromEnd !== undefined && fromEnd !== null) return fromEnd;
  return episode.steps.find((s) => s.status.startsWith("Task completed successfully"))?.t ?? null;
}

/** The caption under the camera: instruction, step shown of how many, success, end state. */
export function caption(episode: EpisodeData | null, index: number, paused: boolean): string {
  if (!episode) return "no episode yet: pick a task and start";
  const step = episode.steps[index];
  const n = episode.steps.length;
  if (!step) return `${episode.start.instruction} · starting…`;
  const parts = [episode.start.instruction, `step ${step.t} (${index + 1} of ${n}${episode.end ? "" : " so far"})`];
  const s = successStep(episode);
  if (s !== null && s <= step.t) parts.push(`success at step ${s}`);
  if (episode.end) parts.push(endWord(episode.end));
  else if (paused) parts.push("paused");
  return parts.join(" · ");
}

export function endWord(end: EpisodeEnd): string {
  return end.success ? "✓ success" : end.stopped ? "■ stopped" : "✗ failed";
}

/** The summary's step count in one phrase that agrees with the caption. */
export function stepsPhrase(end: EpisodeEnd): string {
  const s = end.summary.success_step;
  if (s === undefined || s === null) return `${end.steps} steps`;
  const after = end.steps - s - 1;
  return `${end.steps} steps (success at step ${s}${after > 0 ? `, then ${after} recorded after it` : ""})`;
}

export interface TimingPart {
  key: "env" | "model" | "probes" | "cognition" | "other";
  ms: number;
}

/** Where a step's time went: simulator (with labelling), model, probes, cognition, the rest. */
export function timingParts(timings: Step["timings"]): TimingPart[] {
  const env = timings.env_ms + (timings.label_ms ?? 0);
  const known = env + timings.model_ms + timings.probes_ms + timings.cognition_ms;
  return [
    { key: "env", ms: env },
    { key: "model", ms: timings.model_ms },
    { key: "probes", ms: timings.probes_ms },
    { key: "cognition", ms: timings.cognition_ms },
    { key: "other", ms: Math.max(0, timings.total_ms - known) },
  ];
}

export interface DropState {
  /** Forced open at the shown step. */
  active: boolean;
  /** Steps still to come. */
  left: number;
  /** One line for the page ("" when there is nothing to say). */
  text: string;
}

function grasping(episode: EpisodeData, index: number): boolean | null {
  const truth = episode.truth[index];
  if (!truth) return null;
  return episode.atoms.some((a) => a.predicate === "grasped" && truth[a.index] === 1);
}

/** The drop indicator at step index k: forced open with N steps left, and why a drop did nothing. */
export function dropState(episode: EpisodeData, k: number, requested: boolean): DropState {
  const step = episode.steps[k];
  if (!step) return { active: false, left: 0, text: "" };
  if (step.perturbed) {
    const left = step.drop_left ?? 0;
    const nothing = grasping(episode, k) === false && !dropLostSomething(episode, k);
    const why = nothing ? " · nothing is grasped in the world, so opening the gripper changes nothing" : "";
    return { active: true, left, text: `↓ gripper forced open at step ${step.t}, ${left} step${left === 1 ? "" : "s"} left${why}` };
  }
  if (requested && !episode.end) return { active: false, left: 0, text: "↓ drop requested: applies from the next step" };
  return { active: false, left: 0, text: "" };
}

/** Whether something was grasped in the world at the first step of the drop that includes step k. */
function dropLostSomething(episode: EpisodeData, k: number): boolean {
  let i = k;
  while (i > 0 && episode.steps[i - 1]?.perturbed) i--;
  return grasping(episode, Math.max(0, i - 1)) === true;
}

/** The driver a start asks for: the one picked if the server offers it (a server restarted with `--takeover`
 * offers only "policy"), else the server's default, else the first it offers. */
export function chosenDriver(picked: string, offered: readonly string[], fallback: string | undefined): string {
  if (offered.includes(picked)) return picked;
  if (fallback !== undefined && (offered.length === 0 || offered.includes(fallback))) return fallback;
  return offered[0] ?? "expert";
}
