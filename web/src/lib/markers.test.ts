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
