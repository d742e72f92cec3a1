/**
 * Task picker, init state, driver, start/stop/pause/resume, the drop perturbation with its indicator, and the
 * connection state. Each control is enabled only when it applies; after a reload the pickers show the
 * running episode's task, init and driver.
 */
import { useEffect, useState } from "react";
import type { ConnectionState } from "../lib/connection";
import { chosenDriver, dropState } from "../lib/status";
import type { AppState } from "../useAppState";

interface Choice {
  task: number;
  init: string;
  driver: string;
}

/** The pickers, following the running episode when one starts or is joined. */
function useChoice(state: AppState): [Choice, (patch: Partial<Choice>) => void] {
  const [choice, setChoice] = useState<Choice>({ task: 0, init: "random", driver: "" });
  const live = state.snap.live;
  const runningId = live && !live.end && live.start.source === "live" ? live.id : null;
  useEffect(() => {
    if (!runningId || !live) return;
    setChoice({ task: live.start.task, init: String(live.start.init), driver: live.start.driver });
  }, [runningId]); // only when another episode runs
  return [choice, (patch) => setChoice((c) => ({ ...c, ...patch }))];
}

function connectionText(connection: ConnectionState, retryInMs: number | null): string {
  if (connection === "open") return "● connected";
  if (connection === "connecting") return "◌ connecting…";
  return `○ reconnecting in ${((retryInMs ?? 0) / 1000).toFixed(1)} s`;
}

/** Why Drop does nothing now ("" when it applies). */
function dropBlocked(state: AppState): string {
  const live = state.snap.live;
  if (!state.running || !live) return "drop needs a running episode";
  if (live.start.source === "store") return "drop perturbs the simulator; a store re-run has none";
  return "";
}

function Pickers({ state, choice, set }: { state: AppState; choice: Choice; set: (p: Partial<Choice>) => void }) {
  const hello = state.snap.hello;
  const busy = state.running;
  const driver = chosenDriver(choice.driver, hello?.drivers ?? [], hello?.default_driver);
  return (
    <>
      <label className="task">
        <span>Task</span>
        <select data-testid="task-select" value={choice.task} disabled={busy} onChange={(e) => set({ task: parseInt(e.target.value, 10) })}>
          {(hello?.tasks ?? []).map((t) => (
            <option key={t.index} value={t.index}>
              {t.index}: {t.instruction}
            </option>
          ))}
        </select>
      </label>
      <label>
        <span>Init</span>
        <select data-testid="init-select" value={choice.init} disabled={busy} onChange={(e) => set({ init: e.target.value })}>
          <option value="random">random</option>
          {Array.from({ length: Math.max(hello?.num_init_states ?? 0, choice.init === "random" ? 0 : Number(choice.init) + 1) }, (_, i) => (
            <option key={i} value={String(i)}>
              {i}
            </option>
          ))}
        </select>
      </label>
      <label>
        <span>Driver</span>
        <select
          data-testid="driver-select"
          value={driver}
          disabled={busy}
          onChange={(e) => set({ driver: e.target.value })}
        >
          {(hello?.drivers ?? []).map((d) => (
            <option key={d} value={d}>
              {d}
            </option>
          ))}
        </select>
      </label>
    </>
  );
}

export function ControlBar({ state }: { state: AppState }) {
  const { snap, running, paused, send } = state;
  const [choice, set] = useChoice(state);
  const [maxSteps, setMaxSteps] = useState("");
  const [dropSteps, setDropSteps] = useState("");
  const hello = snap.hello;
  const open = snap.connection === "open";
  const blocked = dropBlocked(state);
  const driver = chosenDriver(choice.driver, hello?.drivers ?? [], hello?.default_driver);
  const live = snap.live;
  const drop = live && !snap.replay ? dropState(live, live.steps.length - 1, state.dropRequested) : null;
  const start = () => {
    const steps = parseInt(maxSteps, 10);
    send({
      type: "start",
      task: choice.task,
      init: choice.init === "random" ? "random" : parseInt(choice.init, 10),
      driver: driver as "expert" | "policy",
      max_steps: Number.isFinite(steps) && steps > 0 ? steps : null,
    });
  };
  const sendDrop = () => {
    const steps = parseInt(dropSteps, 10);
    send({ type: "drop", steps: Number.isFinite(steps) && steps > 0 ? steps : null });
  };
  return (
    <header className="controls" aria-label="controls">
      <Pickers state={state} choice={choice} set={set} />
      <label>
        <span>Max steps</span>
        <input className="num" type="number" min={1} placeholder="server" value={maxSteps} disabled={running} onChange={(e) => setMaxSteps(e.target.value)} />
      </label>
      <div className="buttons">
        <button data-testid="start" disabled={!open || !hello || running} onClick={start} title={running ? "an episode is running: stop it first" : "start the episode"}>
          ▶ Start
        </button>
        <button data-testid="stop" disabled={!open || !running} onClick={() => send({ type: "stop" })}>
          ■ Stop
        </button>
        <button data-testid="pause" disabled={!open || !running} onClick={() => send({ type: paused ? "resume" : "pause" })}>
          {paused ? "▶ Resume" : "❚❚ Pause"}
        </button>
        <button data-testid="drop" disabled={!open || blocked !== ""} onClick={sendDrop} title={blocked || "force the gripper open"}>
          ↓ Drop
        </button>
        <input className="num" type="number" min={1} max={100} placeholder="steps" aria-label="drop steps" value={dropSteps} disabled={blocked !== ""} onChange={(e) => setDropSteps(e.target.value)} />
      </div>
      {hello && (
        <span className="model" data-testid="model" title="hidden states the object / action probes read">
          {hello.model_id} · layers {hello.probes.layers.object}/{hello.probes.layers.action}
        </span>
      )}
      <span className={`connection ${snap.connection}`} data-testid="connection" data-state={snap.connection}>
        {connectionText(snap.connection, snap.retryInMs)}
      </span>
      <div className="drop-line" aria-live="polite" data-testid="drop-indicator" data-active={drop?.active ? "1" : "0"} data-left={drop?.left ?? 0}>
        {drop?.text || (running && blocked ? `↓ ${blocked}` : "")}
      </div>
    </header>
  );
}
