/**
 * The takeover panel (`serve --takeover`): who acts at the shown step (the policy, or the scripted expert in a
 * takeover, with why), and the cognition's alarms so far with their reason, rules and atoms.
 */
import type { EpisodeData } from "../lib/episode";
import { actingAt, actingText, alarmsUntil, takeoversUntil } from "../lib/takeover";

const WHO = { expert: "EXPERT ACTING", policy: "POLICY ACTING" } as const;

/** Rendered only for an episode with takeovers (or a recording whose steps carry alarms or takeovers). */
export function TakeoverPanel({
  episode,
  index,
  length,
  until = "steps",
}: {
  episode: EpisodeData;
  index: number;
  length: number | null;
  until?: "subgoal" | "steps";
}) {
  const steps = episode.steps;
  const mode = episode.start.takeover ?? "none";
  const alarms = alarmsUntil(steps, index);
  const taken = takeoversUntil(steps, index);
  if (mode === "none" && alarms.length === 0 && taken.length === 0) return null;
  const acting = actingAt(steps, index);
  const expertSteps = taken.reduce((n, t) => n + t.steps, 0);
  return (
    <section className="panel takeover" aria-labelledby="takeover-h" data-testid="takeover">
      <h2 id="takeover-h">Takeover ({mode === "random" ? "random control" : "the cognition's alarm"})</h2>
      {acting && (
        <p className={`acting ${acting.who}`} data-testid="acting" data-who={acting.who}>
          <strong>{WHO[acting.who]}</strong> {actingText(acting, length, until)}
        </p>
      )}
      <p className="muted" data-testid="takeover-count">
        {taken.length} takeover{taken.length === 1 ? "" : "s"} so far, {expertSteps} action{expertSteps === 1 ? "" : "s"} by the expert
      </p>
      <h3>Alarms ({alarms.length})</h3>
      <ul className="alarms" data-testid="alarms">
        {alarms.length === 0 && <li className="muted">none yet</li>}
        {alarms.map(({ index: i, t, alarm }) => (
          <li key={i} className="alarm" data-kind={alarm.kind}>
            <span className="icon" aria-hidden="true">⚑</span> step {t}: <strong>{alarm.kind}</strong> {alarm.reason}
            {(alarm.rules.length > 0 || alarm.atoms.length > 0) && (
              <div className="muted">
                {alarm.rules.length > 0 && <>rules {alarm.rules.join(", ")}</>}
                {alarm.rules.length > 0 && alarm.atoms.length > 0 && " · "}
                {alarm.atoms.length > 0 && <>atoms {alarm.atoms.join(", ")}</>}
              </div>
            )}
          </li>
        ))}
      </ul>
    </section>
  );
}
