/**
 * Recorded (live) and stored episodes: open one in the timeline, replay it there (the slider plays at the
 * stream's rate), or, for a store episode, have the server stream it through the probes and the cognition.
 */
import type { EpisodeListItem } from "../messages";

interface Props {
  episodes: EpisodeListItem[];
  error: string | null;
  selected: string | null;
  onOpen: (id: string, play: boolean) => void;
  onStream: (id: string) => void;
  onRefresh: () => void;
}

export function Episodes({ episodes, error, selected, onOpen, onStream, onRefresh }: Props) {
  return (
    <section className="panel episodes" aria-label="episodes">
      <div className="panel-head">
        <h2>Episodes</h2>
        <button onClick={onRefresh} data-testid="refresh-episodes">
          ↻
        </button>
      </div>
      {error && <p className="error">{error}</p>}
      {episodes.length === 0 && <p className="muted">none yet</p>}
      <ul data-testid="episodes">
        {episodes.map((e) => (
          <li key={e.id} data-testid="episode" data-id={e.id} className={e.id === selected ? "selected" : ""}>
            <div>
              <span className="tag">{e.source}</span> task {e.task} · init {e.init} · {e.driver} · {e.steps} steps ·{" "}
              {e.success === null ? "…" : e.success ? "✓ success" : e.stopped ? "■ stopped" : "✗ failed"}
            </div>
            <div className="muted instr">{e.instruction}</div>
            <button data-testid="open-episode" onClick={() => onOpen(e.id, false)}>
              open
            </button>
            <button data-testid="replay-episode" onClick={() => onOpen(e.id, true)}>
              ▶ replay
            </button>
            {e.source === "store" && (
              <button
                data-testid="stream-episode"
                onClick={() => onStream(e.id)}
                title="the server streams it through the probes and the cognition"
              >
                re-run probes
              </button>
            )}
          </li>
        ))}
      </ul>
    </section>
  );
}
