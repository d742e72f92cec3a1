/**
 * The protocol's message types under the names the UI uses. Everything here is derived from the
 * generated `protocol.ts` (from the server's JSON Schema); only the `type` tag is made required so
 * that TypeScript narrows a union of messages by it.
 */
import type * as P from "./protocol";

type Tagged<T extends { type?: unknown }> = Omit<T, "type"> & { type: NonNullable<T["type"]> };

export type Hello = Tagged<P.Hello>;
export type EpisodeStart = Tagged<P.EpisodeStart>;
export type Step = Tagged<P.Step>;
export type History = Omit<Tagged<P.History>, "start" | "steps"> & { start: EpisodeStart; steps: Step[] };
export type EpisodeEnd = Tagged<P.EpisodeEnd>;
export type Status = Tagged<P.Status>;
export type ErrorMessage = Tagged<P.ErrorMessage>;
export type ServerMessage = Hello | EpisodeStart | Step | History | EpisodeEnd | Status | ErrorMessage;

export type StartCommand = Tagged<P.StartCommand>;
export type ClientMessage =
  | StartCommand
  | Tagged<P.StopCommand>
  | Tagged<P.PauseCommand>
  | Tagged<P.ResumeCommand>
  | Tagged<P.DropCommand>
  | Tagged<P.ReplayCommand>;

export type Violation = P.Violation;
export type Alarm = P.Alarm;
export type Takeover = P.Takeover;
export type SubgoalState = P.SubgoalState;
export type EpisodeEvent = P.Event;
export type EpisodeListItem = P.EpisodeListItem;
export type EpisodeRecord = { start: EpisodeStart; steps: Step[]; end: EpisodeEnd | null };

const SERVER_TYPES = new Set(["hello", "episode_start", "step", "history", "episode_end", "status", "error"]);

/** Parses one WebSocket text frame; null when it is not a server message this UI knows. */
export function parseServerMessage(text: string): ServerMessage | null {
  let data: unknown;
  try {
    data = JSON.parse(text);
  } catch {
    return null;
  }
  if (typeof data !== "object" || data === null) return null;
  const type = (data as { type?: unknown }).type;
  return typeof type === "string" && SERVER_TYPES.has(type) ? (data as ServerMessage) : null;
}
