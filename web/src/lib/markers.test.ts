import { expect, test } from "vitest";
import { markersOf } from "./markers";

test("markers: drops, violations where they begin, goals and events by side", () => {
  const v = { rule: "r", message: "bad", atoms: [], since: 1 };
  const m = markersOf([
    { t: 0, violations: [], events: [], truth_events: [] },
    { t: 1, violations: [v], events: [], truth_events: [], perturbed: true },
    { t: 2, violations: [v], events: [{ kind: "goal_reached", t: 2, message: "goal" }], truth_events: [{ kind: "dropped", t: 2, message: "d" }] },
    { t: 3, violations: [], events: [], truth_events: [{ kind: "goal_reached", t: 3, message: "goal" }] },
  ]);
  expect(m.map((x) => [x.index, x.kind])).toEqual([
    [1, "drop"],
    [1, "violation"],
    [2, "goal-predicted"],
    [2, "event-world"],
    [3, "goal-world"],
  ]);
});

test("markers: the alarm, and the handovers to the expert and back", () => {
  const alarm = { kind: "stall" as const, reason: "no subgoal done", rules: [], atoms: ["grasp a"] };
  const takeover = { index: 1, start: 1, reason: "stall: no subgoal done", steps: 1 };
  const m = markersOf([
    { t: 0, violations: [], events: [], alarm },
    { t: 1, violations: [], events: [], takeover, handover: "to_expert" },
    { t: 2, violations: [], events: [], handover: "to_policy" },
  ]);
  expect(m.map((x) => [x.index, x.kind, x.label])).toEqual([
    [0, "alarm", "step 0: alarm, stall: no subgoal done · atoms grasp a"],
    [1, "takeover", "step 1: the expert takes over (stall: no subgoal done)"],
    [2, "takeover", "step 2: the policy acts again"],
  ]);
});
