/** One belief: predicted state (flip and fade), name, probe probability as a small bar, the world's value, agreement. */
import { memo } from "react";
import type { BeliefRow as Row } from "../lib/focus";
import type { AtomState } from "../lib/flips";

export const ICON: Record<AtomState, string> = { "turned-on": "▲", "turned-off": "▼", on: "●", off: "○" };
export const LABEL: Record<AtomState, string> = {
  "turned-on": "turned true",
  "turned-off": "turned false",
  on: "true",
  off: "false",
};

function agreementOf(row: Row): "agree" | "disagree" | "unknown" {
  if (!row.probed || row.truth === null) return "unknown";
  return row.disagree ? "disagree" : "agree";
}

function World({ row, window }: { row: Row; window: number }) {
  if (row.truth === null) return null;
  const flipped = row.worldAge < window;
  const mark = flipped ? (row.truth ? "▲" : "▼") : row.truth ? "●" : "○";
  const words = `world: ${flipped ? (row.truth ? "turned true" : "turned false") : row.truth ? "true" : "false"}`;
  return (
    <span className={`world${flipped ? " flipped" : ""}`} title={words} aria-label={words}>
      W{mark}
    </span>
  );
}

function Prob({ prob }: { prob: number | null }) {
  if (prob === null) return <span className="tag unprobed-tag">not probed</span>;
  return (
    <span className="prob" title={`probe probability ${prob.toFixed(2)}`}>
      <span className="track" aria-hidden="true">
        <span className="bar" style={{ width: `${Math.round(prob * 100)}%` }} />
      </span>
      <span className="p">{prob.toFixed(2)}</span>
    </span>
  );
}

interface RowProps {
  row: Row;
  fade: number;
  window: number;
}

/** Rows are rebuilt every step; a row re-renders only when what it shows changed. */
function sameRow(a: RowProps, b: RowProps): boolean {
  const x = a.row;
  const y = b.row;
  return (
    a.fade.toFixed(2) === b.fade.toFixed(2) &&
    a.window === b.window &&
    x.name === y.name &&
    x.state === y.state &&
    x.truth === y.truth &&
    x.worldAge < a.window === y.worldAge < b.window &&
    x.disagree === y.disagree &&
    x.probed === y.probed &&
    x.pinned === y.pinned &&
    (x.prob ?? -1).toFixed(2) === (y.prob ?? -1).toFixed(2)
  );
}

export const BeliefRowView = memo(function BeliefRowView({ row, fade, window }: RowProps) {
  const agreement = agreementOf(row);
  return (
    <li
      className={`atom ${row.state} ${agreement}${row.probed ? "" : " unprobed"}${row.pinned ? " pinned" : ""}`}
      data-testid="atom"
      data-atom={row.name}
      data-state={row.state}
      data-agree={agreement}
      data-pinned={row.pinned ? "1" : "0"}
      style={{ "--fade": fade.toFixed(2) } as React.CSSProperties}
      title={`${row.name}: predicted ${LABEL[row.state]}${row.truth === null ? "" : `, world ${row.truth ? "true" : "false"}`}`}
    >
      <span className="icon" aria-label={`predicted ${LABEL[row.state]}`}>
        {ICON[row.state]}
      </span>
      <span className="name">{row.name}</span>
      <Prob prob={row.probed ? row.prob : null} />
      <World row={row} window={window} />
      <span className={`agree-tag ${agreement}`}>{agreement === "agree" ? "✓" : agreement === "disagree" ? "✗ differs" : ""}</span>
    </li>
  );
}, sameRow);
