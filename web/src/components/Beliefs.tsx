/**
 * Predicted atoms at one step, grouped by predicate (object head, then action head). Just turned true: green
 * with an up arrow; just turned false: red with a down arrow; both fade over a few steps. Where truth is
 * streamed, each atom shows agree (✓) or disagree (✗), and the header the step's agreement in %.
 */
import { memo, useMemo, useState } from "react";
import { agreementPercent, atomAgreement, type Agreement } from "../lib/agreement";
import { groupByPredicate } from "../lib/atoms";
import type { EpisodeData } from "../lib/episode";
import { type AtomState, type BeliefFilter, atomViewsAt, passesFilter } from "../lib/flips";

const ICON: Record<AtomState, string> = { "turned-on": "▲", "turned-off": "▼", on: "●", off: "○" };
const LABEL: Record<AtomState, string> = {
  "turned-on": "turned true",
  "turned-off": "turned false",
  on: "true",
  off: "false",
};

interface RowProps {
  name: string;
  state: AtomState;
  fade: number;
  agreement: Agreement;
  probed: boolean;
  prob: number | null;
}

const AtomRow = memo(function AtomRow({ name, state, fade, agreement, probed, prob }: RowProps) {
  return (
    <li
      className={`atom ${state} ${agreement}${probed ? "" : " unprobed"}`}
      data-testid="atom"
      data-atom={name}
      data-state={state}
      data-agree={agreement}
      style={{ "--fade": fade.toFixed(2) } as React.CSSProperties}
      title={`${name}: ${LABEL[state]}${prob !== null ? ` (p=${prob.toFixed(2)})` : ""}`}
    >
      <span className="icon" aria-label={LABEL[state]}>
        {ICON[state]}
      </span>
      <span className="name">{name}</span>
      {!probed && <span className="tag">not probed</span>}
      {agreement !== "unknown" && (
        <span className="agree" aria-label={agreement}>
          {agreement === "agree" ? "✓" : "✗ world differs"}
        </span>
      )}
    </li>
  );
});

interface Props {
  episode: EpisodeData;
  index: number;
  fadeSteps: number;
}

export function Beliefs({ episode, index, fadeSteps }: Props) {
  const [filter, setFilter] = useState<BeliefFilter>("all");
  const groups = useMemo(() => groupByPredicate(episode.atoms), [episode.atoms]);
  const predicted = episode.predicted[index];
  const truth = episode.truth[index] ?? null;
  const step = episode.steps[index];
  if (!predicted || !step) {
    return (
      <section className="panel beliefs" aria-label="beliefs">
        <h2>Beliefs</h2>
        <p className="muted">waiting for the first step…</p>
      </section>
    );
  }
  const views = atomViewsAt((j) => episode.predicted[j] ?? [], index, fadeSteps);
  const agreement = atomAgreement(predicted, truth, episode.probed);
  const percent = agreementPercent(predicted, truth, episode.probed);
  const probs = [...step.predicted.object.probs, ...step.predicted.action.probs];
  const disagreeing = agreement.filter((a) => a === "disagree").length;
  const turnedOn = views.filter((v) => v.age === 0 && v.value === 1).length;
  const turnedOff = views.filter((v) => v.age === 0 && v.value === 0).length;
  const world = step.flips.truth;

  return (
    <section className="panel beliefs" aria-label="beliefs">
      <div className="panel-head">
        <h2>Beliefs</h2>
        <span data-testid="agreement" className="agreement-total">
          {percent === null ? "no truth streamed" : `agreement ${percent.toFixed(1)} % (${disagreeing} ✗)`}
        </span>
        <div className="filters" role="radiogroup" aria-label="filter">
          {(["all", "true", "changed"] as const).map((f) => (
            <label key={f}>
              <input
                type="radio"
                name="belief-filter"
                data-testid={`filter-${f}`}
                checked={filter === f}
                onChange={() => setFilter(f)}
              />
              {f}
            </label>
          ))}
        </div>
      </div>
      <div className="flips" data-testid="flips">
        step {step.t}: predicted ▲ {turnedOn} turned true, ▼ {turnedOff} turned false
        {step.truth && (
          <span className="muted">
            {" "}
            · world ▲ {world.on.length} ▼ {world.off.length}
          </span>
        )}
      </div>
      <div className="legend muted">
        ▲ turned true · ▼ turned false (marked for {fadeSteps} steps, fading) · ● true · ○ false · ✓ agrees with the
        world · ✗ differs
      </div>
      <div className="groups">
        {groups.map((g) => {
          const rows = g.atoms.filter((a) => {
            const v = views[a.index];
            return v !== undefined && passesFilter(v, filter);
          });
          if (!rows.length) return null;
          const on = g.atoms.filter((a) => views[a.index]?.value === 1).length;
          return (
            <div className="group" key={`${g.head}:${g.predicate}`} data-predicate={g.predicate}>
              <h3>
                {g.predicate} <span className="muted">{g.head} · {on}/{g.atoms.length} true</span>
              </h3>
              <ul>
                {rows.map((a) => {
                  const v = views[a.index];
                  return v ? (
                    <AtomRow
                      key={a.name}
                      name={a.name}
                      state={v.state}
                      fade={v.fade}
                      agreement={agreement[a.index] ?? "unknown"}
                      probed={a.probed}
                      prob={probs[a.index] ?? null}
                    />
                  ) : null;
                })}
              </ul>
            </div>
          );
        })}
      </div>
    </section>
  );
}
