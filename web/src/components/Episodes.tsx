/**
 * Recorded (live) and stored episodes: open one in the timeline, replay it there (the slider plays at the
 * stream's rate), or, for a store episode, have the server re-run it through the probes and the cognition.
 * The running episode shows its steps so far.
 */
import type { EpisodeListItem } from "../messages";
import type { AppState } from "../useAppState";

function outcome(e: EpisodeListItem, running: boolean): string {
  if (running) return "● running";
  if (e.success === null) return "cut short";
  return e.success ? "✓ success" : e.stopped ? "■ stopped" : "✗ failed";
}

export function Episodes({ state }: { state: AppState }) {
  const { episodes, listError, snap } = state;
  const live = snap.live && !snap.live.end ? snap.live : null;
  const selected = snap.replay?.id ?? null;
  const busy = state.running;
  return (
    <section className="panel episodes" aria-labelledby="episodes-h">
      <div className="panel-head">
        <h2 id="episodes-h">Episodes</h2>
        <button onClick={state.refresh} data-testid="refresh-episodes" aria-label="refresh the list">
          ↻
        </button>
      </div>
      {listError && <p className="error">{listError}</p>}
      {episodes.length === 0 && <p className="muted">none yet</p>}
      <ul data-testid="episodes">
        {episodes.map((e) => {
          const running = live?.id === e.id;
          const steps = running && live ? live.steps.length : e.steps;
          return (
            <li key={e.id} data-testid="episode" data-id={e.id} className={e.id === selected ? "selected" : ""}>
              <div>
                <span className="tag">{e.source}</span> task {e.task} · init {e.init} · {e.driver} · {steps} steps
                {running ? " so far" : ""} · {outcome(e, running)}
              </div>
              <div className="muted instr">{e.instruction}</div>
              <button data-testid="open-episode" onClick={() => state.openEpisode(e.id, false)}>
                open
              </button>
              <button data-testid="replay-episode" onClick={() => state.openEpisode(e.id, true)}>
                ▶ replay
              </button>
              {e.source === "store" && (
                <button
                  data-testid="stream-episode"
                  onClick={() => state.rerunEpisode(e.id)}
                  disabled={busy}
                  title={busy ? "an episode is running" : "the server streams it through the probes and the cognition"}
                >
                  re-run probes
                </button>
              )}
            </li>
          );
        })}
      </ul>
    </section>
  );
}
