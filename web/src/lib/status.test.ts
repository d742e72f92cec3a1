import { expect, test } from "vitest";
import { addStep, newEpisode } from "./episode";
import { fakeStart, fakeStep } from "./fixtures";
import { caption, chosenDriver, dropState, stepsPhrase, streamKind, successStep, timingParts } from "./status";

const end = (steps: number, success_step: number | null) => ({
  type: "episode_end" as const,
  episode_id: "e",
  success: success_step !== null,
  steps,
  stopped: false,
  summary: { violations: {}, goal_step_predicted: null, goal_step_truth: null, agreement: 1, success_step },
});

test("stream kinds: live, store re-run, recorded, stored", () => {
  const live = newEpisode(fakeStart("e"));
  const store = newEpisode({ ...fakeStart("s"), source: "store", store_episode: "store-x" });
  expect([streamKind(live, false), streamKind(store, false), streamKind(live, true), streamKind(store, true)]).toEqual([
    "live",
    "store re-run",
    "recorded",
    "stored",
  ]);
});

test("caption and summary agree on the step counts (success step vs steps recorded)", () => {
  const ep = newEpisode(fakeStart("e"));
  expect(caption(null, 0, false)).toContain("pick a task");
  expect(caption(ep, 0, false)).toBe("pick up the bowl · starting…");
  for (let t = 0; t < 4; t++) addStep(ep, fakeStep("e", t, [0, 0], [0]));
  ep.steps[2]!.status = "Task completed successfully in 2 steps!";
  expect(successStep(ep)).toBe(2);
  expect(caption(ep, 1, true)).toBe("pick up the bowl · step 1 (2 of 4 so far) · paused");
  expect(caption(ep, 3, false)).toBe("pick up the bowl · step 3 (4 of 4 so far) · success at step 2");
  ep.end = end(4, 2);
  expect(caption(ep, 3, false)).toBe("pick up the bowl · step 3 (4 of 4) · success at step 2 · ✓ success");
  expect(stepsPhrase(end(160, 149))).toBe("160 steps (success at step 149, then 10 recorded after it)");
  expect(stepsPhrase(end(30, null))).toBe("30 steps");
});

test("timings: env with labelling, model, probes, cognition and the rest", () => {
  const parts = timingParts({ env_ms: 100, label_ms: 4, model_ms: 60, probes_ms: 0.1, cognition_ms: 0.4, driver_ms: 1, total_ms: 170 });
  expect(parts.map((p) => [p.key, Math.round(p.ms * 10) / 10])).toEqual([
    ["env", 104],
    ["model", 60],
    ["probes", 0.1],
    ["cognition", 0.4],
    ["other", 5.5],
  ]);
});

test("drop indicator: steps left, the reason when nothing was grasped, a pending request", () => {
  const start = fakeStart("e", ["on(a,b)"], ["grasped(a)"]);
  const ep = newEpisode(start);
  const step = (t: number, grasped: number, perturbed: boolean, left: number) => ({
    ...fakeStep("e", t, [0], [grasped]),
    perturbed,
    drop_left: left,
  });
  addStep(ep, step(0, 0, false, 0));
  addStep(ep, step(1, 0, true, 1));
  addStep(ep, step(2, 1, false, 0));
  addStep(ep, step(3, 1, true, 2));
  addStep(ep, step(4, 0, true, 1));
  expect(dropState(ep, 0, false)).toEqual({ active: false, left: 0, text: "" });
  expect(dropState(ep, 0, true).text).toContain("drop requested");
  expect(dropState(ep, 1, false).text).toBe(
    "↓ gripper forced open at step 1, 1 step left · nothing is grasped in the world, so opening the gripper changes nothing",
  );
  expect(dropState(ep, 3, false)).toEqual({ active: true, left: 2, text: "↓ gripper forced open at step 3, 2 steps left" });
  expect(dropState(ep, 4, false).text).toBe("↓ gripper forced open at step 4, 1 step left"); // it held the object when the drop began
  expect(dropState(ep, 9, false).text).toBe("");
});

test("the driver a start asks for is one the server offers", () => {
  expect(chosenDriver("expert", ["expert", "policy"], "expert")).toBe("expert");
  expect(chosenDriver("", ["expert", "policy"], "policy")).toBe("policy");
  expect(chosenDriver("expert", ["policy"], "policy")).toBe("policy"); // picked before a --takeover restart
  expect(chosenDriver("expert", ["policy"], "expert")).toBe("policy");
  expect(chosenDriver("", [], undefined)).toBe("expert");
});
