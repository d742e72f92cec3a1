/**
 * The camera frame (live at the stream's rate, or the timeline's step), resizable by its corner; the
 * measured frames per second; and where the shown step's time went (simulator, model, probes, cognition).
 */
import { useState } from "react";
import type { Step } from "../messages";
import { timingParts } from "../lib/status";

interface Props {
  src: string | null;
  fps: number | null;
  caption: string;
  step: Step | null;
}

const PART_LABEL = { env: "simulator", model: "model", probes: "probes", cognition: "cognition", other: "other" } as const;

function Timings({ step }: { step: Step }) {
  const parts = timingParts(step.timings);
  const total = Math.max(step.timings.total_ms, 1e-6);
  const rate = 1000 / total;
  return (
    <div className="timings" data-testid="timings" title="where this step's time went">
      <div className="timing-bar" aria-hidden="true">
        {parts.map((p) => (
          <span key={p.key} className={`part ${p.key}`} style={{ width: `${(100 * p.ms) / total}%` }} />
        ))}
      </div>
      <div className="timing-text">
        {total.toFixed(0)} ms/step (≤ {rate.toFixed(1)} steps/s):{" "}
        {parts
          .filter((p) => p.ms >= 0.05)
          .map((p) => `${PART_LABEL[p.key]} ${p.ms < 10 ? p.ms.toFixed(1) : p.ms.toFixed(0)}`)
          .join(" · ")}
      </div>
    </div>
  );
}

export function Camera({ src, fps, caption, step }: Props) {
  const [missing, setMissing] = useState<string | null>(null);
  const shown = src && src !== missing ? src : null;
  return (
    <section className="panel camera" aria-label="camera">
      <div className="frame" data-testid="camera-frame" title="drag the corner to resize">
        {shown ? (
          <img data-testid="camera" src={shown} alt={caption} onError={() => setMissing(src)} />
        ) : (
          <div className="noframe" data-testid="camera-empty">
            no frame
          </div>
        )}
      </div>
      <div className="caption">
        <span data-testid="status">{caption}</span>
        {fps !== null && <span data-testid="fps">{fps.toFixed(1)} fps</span>}
      </div>
      {step && <Timings step={step} />}
    </section>
  );
}
