/** Task picker, init state, driver, start/stop/pause/resume, the drop perturbation, and the connection state. */
import { useState } from "react";
import type { ClientMessage, Hello } from "../messages";
import type { ConnectionState } from "../lib/connection";

interface Props {
  hello: Hello | null;
  connection: ConnectionState;
  retryInMs: number | null;
  running: boolean;
  /** The server's word on pause (a status message or hello), so every client shows the same state. */
  paused: boolean;
  send: (msg: ClientMessage) => void;
}

export function ControlBar({ hello, connection, retryInMs, running, paused, send }: Props) {
  const [task, setTask] = useState(0);
  const [init, setInit] = useState<string>("random");
  const [driver, setDriver] = useState<string>("");
  const [maxSteps, setMaxSteps] = useState<string>("");
  const [dropSteps, setDropSteps] = useState<string>("");
  const drivers = hello?.drivers ?? [];
  const chosenDriver = (driver || hello?.default_driver || "expert") as "expert" | "policy";
  const open = connection === "open";

  const start = () => {
    const steps = parseInt(maxSteps, 10);
    send({
      type: "start",
      task,
      init: init === "random" ? "random" : parseInt(init, 10),
      driver: chosenDriver,
      max_steps: Number.isFinite(steps) && steps > 0 ? steps : null,
    });
  };
  const togglePause = () => send({ type: paused ? "resume" : "pause" });
  const drop = () => {
    const steps = parseInt(dropSteps, 10);
    send({ type: "drop", steps: Number.isFinite(steps) && steps > 0 ? steps : null });
  };

  return (
    <header className="controls" aria-label="controls">
      <label className="task">
        <span>Task</span>
        <select data-testid="task-select" value={task} onChange={(e) => setTask(parseInt(e.target.value, 10))}>
          {(hello?.tasks ?? []).map((t) => (
            <option key={t.index} value={t.index}>
              {t.index}: {t.instruction}
            </option>
          ))}
        </select>
      </label>
      <label>
        <span>Init</span>
        <select data-testid="init-select" value={init} onChange={(e) => setInit(e.target.value)}>
          <option value="random">random</option>
          {Array.from({ length: hello?.num_init_states ?? 0 }, (_, i) => (
            <option key={i} value={String(i)}>
              {i}
            </option>
          ))}
        </select>
      </label>
      <label>
        <span>Driver</span>
        <select data-testid="driver-select" value={chosenDriver} onChange={(e) => setDriver(e.target.value)}>
          {drivers.map((d) => (
            <option key={d} value={d}>
              {d}
            </option>
          ))}
        </select>
      </label>
      <label>
        <span>Max steps</span>
        <input
          className="num"
          type="number"
          min={1}
          placeholder="server"
          value={maxSteps}
          onChange={(e) => setMaxSteps(e.target.value)}
        />
      </label>
      <div className="buttons">
        <button data-testid="start" disabled={!open || !hello} onClick={start}>
          ▶ Start
        </button>
        <button data-testid="stop" disabled={!open || !running} onClick={() => send({ type: "stop" })}>
          ■ Stop
        </button>
        <button data-testid="pause" disabled={!open || !running} onClick={togglePause}>
          {paused ? "▶ Resume" : "❚❚ Pause"}
        </button>
        <button data-testid="drop" disabled={!open || !running} onClick={drop} title="force the gripper open">
          ↓ Drop
        </button>
        <input
          className="num"
          type="number"
          min={1}
          max={100}
          placeholder="steps"
          aria-label="drop steps"
          value={dropSteps}
          onChange={(e) => setDropSteps(e.target.value)}
        />
      </div>
      {hello && (
        <span className="model muted" data-testid="model" title="hidden states the object / action probes read">
          {hello.model_id} · layers {hello.probes.layers.object}/{hello.probes.layers.action}
        </span>
      )}
      <span className={`connection ${connection}`} data-testid="connection" data-state={connection}>
        {connection === "open" ? "● connected" : connection === "connecting" ? "◌ connecting…" : `○ reconnecting in ${((retryInMs ?? 0) / 1000).toFixed(1)} s`}
      </span>
    </header>
  );
}
