/**
 * The cognition at the shown step: active violations and their history; the subgoals and progress as the
 * predictions see them beside the world's, with the drift between them; the events of both sides on one list.
 */
import type { EpisodeData } from "../lib/episode";
import type { Step, SubgoalState } from "../messages";
import { type SidedEvent, type SubgoalDrift, mergedEvents, subgoalDrift } from "../lib/drift";
import { violationHistory } from "../lib/cognition";

const SUBGOAL_ICON: Record<string, string> = { pending: "○", active: "◐", done: "✓", regressed: "↺" };
const SIDE_MARK = { predicted: "◆ predicted", world: "■ world" } as const;

function Violations({ episode, index }: { episode: EpisodeData; index: number }) {
  const step = episode.steps[index];
  const active = step?.violations ?? [];
  const past = violationHistory(episode.steps, index)
    .filter((s) => s.until !== null)
    .reverse();
  return (
    <>
      <h3>Active violations ({active.length})</h3>
      <ul data-testid="violations" className="violations">
        {active.length === 0 && <li className="muted">none</li>}
        {active.map((v) => (
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
    </>
  );
}

function Side({ title, subgoals, progress, done, testid }: { title: string; subgoals: SubgoalState[] | null; progress: number | null; done: (g: SubgoalState) => number | null; testid: string }) {
  return (
    <div className="side" data-testid={testid}>
      <h4>{title}</h4>
      {subgoals === null || progress === null ? (
        <p className="muted">no world truth in this stream</p>
      ) : (
        <>
          <div className="progress">
            <progress data-testid={`${testid}-progress`} max={1} value={progress} aria-label={`${title} progress`} />
            <span>{Math.round(progress * 100)} %</span>
          </div>
          <ol className="subgoals">
            {subgoals.map((g) => (
              <li key={g.index} className={`subgoal ${g.status}`} data-status={g.status}>
                <span className="icon" aria-hidden="true">
                  {SUBGOAL_ICON[g.status] ?? "?"}
                </span>{" "}
                {g.name} <span className="status">{g.status}{g.status === "done" ? ` (step ${done(g) ?? "?"})` : ""}</span>
              </li>
            ))}
          </ol>
        </>
      )}
    </div>
  );
}

function Subgoals({ episode, index, step }: { episode: EpisodeData; index: number; step: Step | undefined }) {
  const names = episode.start.subgoals;
  const drift = subgoalDrift(names, episode.steps, index);
  const byIndex = new Map<number, SubgoalDrift>(drift.map((d) => [d.index, d]));
  const pending = names.map((s) => ({ ...s, status: "pending" as const }));
  const hasWorld = !!step?.truth && (step.truth_subgoals?.length ?? 0) > 0;
  const drifts = drift.filter((d) => d.text);
  return (
    <>
      <h3>Subgoals: predicted vs world</h3>
      <div className="compare" data-testid="subgoals">
        <Side title="predicted" subgoals={step?.subgoals ?? pending} progress={step?.progress ?? 0} done={(g) => byIndex.get(g.index)?.predicted ?? null} testid="subgoals-predicted" />
        <Side
          title="world"
          subgoals={hasWorld ? (step?.truth_subgoals ?? null) : null}
          progress={hasWorld ? (step?.truth_progress ?? null) : null}
          done={(g) => byIndex.get(g.index)?.world ?? null}
          testid="subgoals-world"
        />
      </div>
      {drifts.length > 0 && (
        <ul className="drift" data-testid="drift">
          {drifts.map((d) => (
            <li key={d.index}>⚠ {d.text}</li>
          ))}
        </ul>
      )}
    </>
  );
}

function Events({ events }: { events: SidedEvent[] }) {
  return (
    <ul className="events" data-testid="events">
      {events.length === 0 && <li className="muted">none yet</li>}
      {events.slice(0, 60).map(({ side, event: e }, i) => (
        <li key={events.length - i} className={`event ${side}`} data-side={side}>
          <span className={`side-tag ${side}`}>{SIDE_MARK[side]}</span> <span className="muted">t={e.t}</span> {e.kind.replace("_", " ")}: {e.message}
        </li>
      ))}
    </ul>
  );
}

export function Cognition({ episode, index }: { episode: EpisodeData; index: number }) {
  const step = episode.steps[index];
  return (
    <section className="panel cognition" aria-labelledby="cognition-h">
      <h2 id="cognition-h">Cognition</h2>
      <Subgoals episode={episode} index={index} step={step} />
      <Violations episode={episode} index={index} />
      <h3>Events (◆ from the predictions, ■ in the world)</h3>
      <Events events={mergedEvents(episode.steps, index)} />
    </section>
  );
}
