import { expect, test } from "vitest";
import { doneSteps, driftText, mergedEvents, subgoalDrift } from "./drift";

const sg = (status: "pending" | "active" | "done" | "regressed") => [{ index: 1, name: "grasped", status }];
const steps = [
  { t: 0, subgoals: sg("active"), truth_subgoals: sg("active") },
  { t: 1, subgoals: sg("done"), truth_subgoals: sg("active") },
  { t: 2, subgoals: sg("done"), truth_subgoals: sg("active") },
  { t: 3, subgoals: sg("done"), truth_subgoals: sg("done") },
  { t: 4, subgoals: sg("regressed"), truth_subgoals: sg("done") },
];

test("done steps per side, reset by a regression", () => {
  expect(doneSteps(steps, 2, "predicted").get(1)).toBe(1);
  expect(doneSteps(steps, 2, "world").get(1)).toBeNull();
  expect(doneSteps(steps, 4, "predicted").get(1)).toBeNull();
  expect(doneSteps(steps, 4, "world").get(1)).toBe(3);
});

test("drift in words: early, late, one side only", () => {
  expect(subgoalDrift([{ index: 1, name: "grasped" }], steps, 3)).toEqual([
    { index: 1, name: "grasped", predicted: 1, world: 3, drift: -2, text: "predicted grasped 2 steps early" },
  ]);
  expect(subgoalDrift([{ index: 1, name: "grasped" }], steps, 2)[0]?.text).toBe("predicted grasped done (step 1); not done in the world");
  expect(driftText("grasp", 78, 54)).toBe("predicted grasp 24 steps late");
  expect(driftText("grasp", 30, 54)).toBe("predicted grasp 24 steps early");
  expect(driftText("grasp", 5, 4)).toBe("predicted grasp 1 step late");
  expect(driftText("grasp", 5, 5)).toBe("");
  expect(driftText("grasp", null, 5)).toBe("grasp done in the world (step 5); not predicted");
  expect(driftText("grasp", null, null)).toBe("");
  expect(subgoalDrift([{ index: 1, name: "g" }], [{ t: 0, subgoals: sg("done") }], 0)[0]?.world).toBeNull(); // no truth
});

test("events of both sides on one list, newest first, marked", () => {
  const ev = (t: number, kind: "dropped" | "goal_reached") => ({ t, kind, message: `${kind}@${t}` });
  const list = mergedEvents(
    [
      { events: [ev(0, "goal_reached")], truth_events: [] },
      { events: [], truth_events: [ev(1, "dropped")] },
      { events: [ev(2, "dropped")], truth_events: [ev(2, "goal_reached")] },
    ],
    2,
  );
  expect(list.map((e) => [e.side, e.event.t])).toEqual([
    ["world", 2],
    ["predicted", 2],
    ["world", 1],
    ["predicted", 0],
  ]);
});
