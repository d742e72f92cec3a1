/**
 * The beliefs at the shown step. Focused view (default): the task-relevant atoms (every action atom and the
 * atoms that mention the task's objects) pinned on top, disagreements with the world first; filters for
 * "disagrees with the world", "changed (predicted or world)" and "true"; atoms without a probe hidden until
 * asked for. Off: every atom grouped by predicate (the paper's order).
 */
import { useMemo, useState } from "react";
import { agreementPercent } from "../lib/agreement";
import { beliefGroups, beliefRows, episodeObjects } from "../lib/beliefRows";
import type { EpisodeData } from "../lib/episode";
import { type BeliefRow, type RowFilter, type RowOptions, focusedSections, passes } from "../lib/focus";
import { BeliefRowView } from "./BeliefRow";

const FILTERS: [RowFilter, string][] = [
  ["all", "all"],
  ["disagree", "disagrees with the world"],
  ["changed", "changed (predicted or world)"],
  ["true", "predicted true"],
];

function fadeOf(row: BeliefRow, window: number): number {
  return row.age < window ? 1 - row.age / window : 0;
}

function names(list: readonly string[], max = 6): string {
  if (list.length === 0) return "none";
  return list.length <= max ? list.join(", ") : `${list.slice(0, max).join(", ")} and ${list.length - max} more`;
}

function RowList({ rows, window, testid }: { rows: BeliefRow[]; window: number; testid: string }) {
  return (
    <ul className="atom-list" data-testid={testid}>
      {rows.map((r) => (
        <BeliefRowView key={r.name} row={r} fade={fadeOf(r, window)} window={window} />
      ))}
    </ul>
  );
}

function Focused({ rows, opts }: { rows: BeliefRow[]; opts: RowOptions }) {
  const s = focusedSections(rows, opts);
  const pinnedTotal = rows.filter((r) => r.pinned).length;
  return (
    <>
      <h3>
        Task-relevant: {s.pinned.length} shown of {pinnedTotal} <span className="muted">(the task's objects and every action atom)</span>
      </h3>
      <RowList rows={s.pinned} window={opts.window} testid="pinned" />
      <h3>Other atoms: {s.other.length} shown</h3>
      <RowList rows={s.other} window={opts.window} testid="others" />
    </>
  );
}

function Grouped({ episode, rows, opts }: { episode: EpisodeData; rows: BeliefRow[]; opts: RowOptions }) {
  const groups = beliefGroups(episode.atoms, rows);
  return (
    <div className="groups">
      {groups.map((g) => {
        const shown = g.rows.filter((r) => passes(r, opts));
        if (!shown.length) return null;
        const on = g.rows.filter((r) => r.value === 1).length;
        return (
          <div className="group" key={`${g.head}:${g.predicate}`} data-predicate={g.predicate}>
            <h3>
              {g.predicate} <span className="muted">{g.head} · {on}/{g.rows.length} true</span>
            </h3>
            <RowList rows={shown} window={opts.window} testid="group" />
          </div>
        );
      })}
    </div>
  );
}

function Options({ opts, set, focused, setFocused, unprobed }: { opts: RowOptions; set: (o: RowOptions) => void; focused: boolean; setFocused: (f: boolean) => void; unprobed: number }) {
  return (
    <div className="belief-options">
      <label>
        <input type="checkbox" data-testid="focused-toggle" checked={focused} onChange={(e) => setFocused(e.target.checked)} /> focused view
      </label>
      <fieldset className="filters">
        <legend className="sr-only">show</legend>
        {FILTERS.map(([f, label]) => (
          <label key={f}>
            <input type="radio" name="belief-filter" data-testid={`filter-${f}`} checked={opts.filter === f} onChange={() => set({ ...opts, filter: f })} />
            {label}
          </label>
        ))}
      </fieldset>
      <label>
        <input type="checkbox" data-testid="show-unprobed" checked={opts.showUnprobed} onChange={(e) => set({ ...opts, showUnprobed: e.target.checked })} /> show the {unprobed} atoms
        without a probe
      </label>
    </div>
  );
}

export function Beliefs({ episode, index, fadeSteps }: { episode: EpisodeData; index: number; fadeSteps: number }) {
  const [opts, setOpts] = useState<RowOptions>({ filter: "all", showUnprobed: false, window: fadeSteps });
  const [focused, setFocused] = useState(true);
  const objects = useMemo(() => episodeObjects(episode), [episode]);
  const rows = beliefRows(episode, index, fadeSteps, objects);
  const step = episode.steps[index];
  const predicted = episode.predicted[index];
  if (!step || !predicted) {
    return (
      <section className="panel beliefs" aria-labelledby="beliefs-h" id="beliefs" tabIndex={-1}>
        <h2 id="beliefs-h">Beliefs</h2>
        <p className="muted">waiting for the first step…</p>
      </section>
    );
  }
  const percent = agreementPercent(predicted, episode.truth[index] ?? null, episode.probed);
  const wrong = rows.filter((r) => r.disagree);
  const pinnedWrong = wrong.filter((r) => r.pinned).length;
  const unprobed = rows.filter((r) => !r.probed).length;
  const flips = step.flips;
  return (
    <section className="panel beliefs" aria-labelledby="beliefs-h" id="beliefs" tabIndex={-1}>
      <div className="panel-head">
        <h2 id="beliefs-h">Beliefs</h2>
        <span data-testid="agreement" className="agreement-total">
          {percent === null ? "no truth streamed" : `agreement ${percent.toFixed(1)} % (${wrong.length} ✗, ${pinnedWrong} task-relevant)`}
        </span>
      </div>
      <Options opts={opts} set={setOpts} focused={focused} setFocused={setFocused} unprobed={unprobed} />
      <div className="flips" data-testid="flips">
        step {step.t}: predicted ▲ {names(flips.predicted.on)} · ▼ {names(flips.predicted.off)}
        {step.truth && (
          <>
            <br />
            <span data-testid="world-flips">
              world ▲ {names(flips.truth.on)} · ▼ {names(flips.truth.off)}
            </span>
          </>
        )}
      </div>
      <div className="legend">
        predicted: ▲ turned true · ▼ turned false (marked {fadeSteps} steps, fading) · ● true · ○ false · bar: probe probability
        · W● / W○ the world's value (W▲ W▼ just flipped) · ✓ agrees · ✗ differs
      </div>
      {focused ? <Focused rows={rows} opts={opts} /> : <Grouped episode={episode} rows={rows} opts={opts} />}
    </section>
  );
}
