/** Small protocol messages for the unit tests. */
import type { EpisodeStart, Step } from "../messages";

export function fakeStart(id = "ep1", objectAtoms = ["on(a,b)", "left-of(a,b)"], actionAtoms = ["grasped(a)"]): EpisodeStart {
  return {
    type: "episode_start",
    episode_id: id,
    source: "live",
    task: 0,
    instruction: "pick up the bowl",
    init: 0,
    driver: "expert",
    max_steps: 300,
    atoms: { object: objectAtoms, action: actionAtoms },
    probed: { object: objectAtoms.map(() => true), action: actionAtoms.map(() => true) },
    subgoals: [{ index: 0, name: "grasp a" }],
  };
}

export function fakeStep(id: string, t: number, object: number[], action: number[], image: string | null = null): Step {
  return {
    type: "step",
    episode_id: id,
    t,
    image,
    status: `Executing step ${t}`,
    step: t,
    predicted: {
      object: { values: object, probs: object.map((v) => v) },
      action: { values: action, probs: action.map((v) => v) },
    },
    truth: { object, action },
    flips: { predicted: { on: [], off: [] }, truth: { on: [], off: [] } },
    beliefs: { asserted: [], retracted: [] },
    violations: [],
    subgoals: [{ index: 0, name: "grasp a", status: "active" }],
    progress: 0,
    events: [],
    action: null,
    predicted_action: null,
    timings: { env_ms: 1, model_ms: 1, probes_ms: 1, cognition_ms: 1, total_ms: 4 },
  };
}
