/** What is shown: a live stream, a store re-run, or an opened recording, with its driver and step count; and the errors. */
import type { AppState } from "../useAppState";
import { streamKind } from "../lib/status";

const KIND_NOTE: Record<string, string> = {
  live: "the simulator runs now; scrub back any time",
  "store re-run": "a stored episode streamed through the probes and the cognition (no simulator: drop does not apply)",
  recorded: "a recorded live episode, opened from the list",
  stored: "an activation-store episode, opened from the list",
};

export function StreamBanner({ state, onClose }: { state: AppState; onClose: () => void }) {
  const { episode, snap } = state;
  if (!episode) return null;
  const opened = !!snap.replay;
  const kind = streamKind(episode, opened);
  const running = !opened && !episode.end;
  const start = episode.start;
  return (
    <div className={`banner kind-${kind.replace(" ", "-")}`} role="status" data-testid="stream-banner" data-kind={kind}>
      <strong className="kind">{running ? "● " : ""}{kind.toUpperCase()}</strong>
      <span>
        task {start.task} · init {start.init} · driver {start.driver}
        {start.takeover && start.takeover !== "none" ? ` · takeover ${start.takeover}` : ""}
        {start.store_episode ? ` · re-run of ${start.store_episode}` : ""} · {episode.id}
        {!running && !opened ? " · ended" : ""}
      </span>
      <span className="muted">{running || opened ? KIND_NOTE[kind] : "ended: scrub it here, or open it from the episodes list"}</span>
      {opened && (
        <button data-testid="back-to-live" onClick={onClose}>
          close: back to live
        </button>
      )}
    </div>
  );
}

export function Errors({ errors, onDismiss }: { errors: string[]; onDismiss: () => void }) {
  if (errors.length === 0) return null;
  return (
    <div className="errors" role="alert" data-testid="errors">
      {errors.map((e, i) => (
        <div key={i}>⚠ {e}</div>
      ))}
      <button onClick={onDismiss}>dismiss</button>
    </div>
  );
}
