import { expect, test } from "vitest";
import { eventsUntil, violationHistory } from "./cognition";

const v = (rule: string, since: number) => ({ rule, message: `${rule} broken`, atoms: ["on(a,b)"], since });

test("violation spans: active ones open, resolved ones closed", () => {
  const steps = [
    { violations: [] },
    { violations: [v("r1", 1)] },
    { violations: [v("r1", 1), v("r2", 2)] },
    { violations: [v("r2", 2)] },
  ];
  const h = violationHistory(steps, 3);
  expect(h.map((s) => [s.violation.rule, s.from, s.until])).toEqual([
    ["r1", 1, 2],
    ["r2", 2, null],
  ]);
  expect(violationHistory(steps, 1).map((s) => [s.violation.rule, s.until])).toEqual([["r1", null]]);
});

test("events up to a step, newest first", () => {
  const e = (t: number) => ({ kind: "subgoal_done" as const, t, message: `m${t}` });
  const steps = [{ events: [e(0)] }, { events: [], truth_events: [e(1)] }, { events: [e(2)] }];
  expect(eventsUntil(steps, 2).map((x) => x.t)).toEqual([2, 0]);
  expect(eventsUntil(steps, 1).map((x) => x.t)).toEqual([0]);
  expect(eventsUntil(steps, 2, "truth").map((x) => x.t)).toEqual([1]);
});
