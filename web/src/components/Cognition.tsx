/** Active violations (rule message, atoms, since), their history, the subgoals with progress, and the events. */
import type { EpisodeData } from "../lib/episode";
import type { EpisodeEvent } from "../messages";
import { eventsUntil, violationHistory } from "../lib/cognition";

const SUBGOAL_ICON: Record<string, string> = { pending: "○", active: "◐", done: "✓", regressed: "↺" };

export function Cognition({ episode, index }: { episode: EpisodeData; index: number }) {
  const step = episode.steps[index];
  const spans = violationHistory(episode.steps, index);
  const past = spans.filter((s) => s.until !== null).reverse();
  const events = eventsUntil(episode.steps, index);
  const worldEvents = eventsUntil(episode.steps, index, "truth");
  const progress = step?.progress ?? 0;
  return (
    <section className="panel cognition" aria-label="cognition">
      <h2>Cognition</h2>
      <h3>Active violations ({step?.violations.length ?? 0})</h3>
      <ul data-testid="violations" className="violations">
        {(step?.violations ?? []).length === 0 && <li className="muted">none</li>}
        {(step?.violations ?? []).map((v) => (
          <li key={`${v.rule}|${v.atoms.join(",")}|${v.since}`} className="violation" data-rule={v.rule}>
            <span className="icon">⚠</span> <strong>{v.message}</strong>
            <div className="muted">
              {v.rule} · since step {v.since} · {v.atoms.join(", ")}
            </div>
          </li>
        ))}
      </ul>
      {past.length > 0 && (
        <details>
          <summary>Resolved violations ({past.length})</summary>
          <ul className="violations past">
            {past.map((s) => (
              <li key={`${s.violation.rule}|${s.violation.atoms.join(",")}|${s.from}`}>
                {s.violation.message} <span className="muted">steps {s.from}–{s.until}</span>
              </li>
            ))}
          </ul>
        </details>
      )}
      <h3>Subgoals</h3>
      <div className="progress">
        <progress data-testid="progress" max={1} value={progress} />
        <span>{Math.round(progress * 100)} %</span>
      </div>
      <ol className="subgoals" data-testid="subgoals">
        {(step?.subgoals ?? episode.start.subgoals.map((s) => ({ ...s, status: "pending" as const }))).map((s) => (
          <li key={s.index} className={`subgoal ${s.status}`} data-status={s.status}>
            <span className="icon">{SUBGOAL_ICON[s.status] ?? "?"}</span> {s.name} <span className="muted">{s.status}</span>
          </li>
        ))}
      </ol>
      <h3>Events (from the predictions)</h3>
      <EventList events={events} testid="events" />
      <h3>Events in the world (from the true atoms)</h3>
      <EventList events={worldEvents} testid="world-events" />
    </section>
  );
}

function EventList({ events, testid }: { events: EpisodeEvent[]; testid: string }) {
  return (
    <ul className="events" data-testid={testid}>
      {events.length === 0 && <li className="muted">none yet</li>}
      {events.slice(0, 50).map((e, i) => (
        <li key={`${e.t}-${e.kind}-${i}`} className={`event ${e.kind}`}>
          <span className="muted">t={e.t}</span> {e.kind.replace("_", " ")}: {e.message}
        </li>
      ))}
    </ul>
  );
}
