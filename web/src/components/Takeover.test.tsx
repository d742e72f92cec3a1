import { renderToStaticMarkup } from "react-dom/server";
import { expect, test } from "vitest";
import { addStep, newEpisode } from "../lib/episode";
import { fakeStart, fakeStep } from "../lib/fixtures";
import { TakeoverPanel } from "./Takeover";

const alarm = { kind: "stall" as const, reason: "no subgoal done for 4 steps (next: grasp a)", rules: [], atoms: ["grasp a"] };

function episode(mode: "none" | "alarm") {
  const e = newEpisode({ ...fakeStart("ep1"), takeover: mode });
  const takeover = { index: 1, start: 2, reason: `stall: ${alarm.reason}`, steps: 1 };
  const extra = [{}, { alarm }, { takeover, handover: "to_expert" as const }, { takeover: { ...takeover, steps: 2 } }];
  extra.forEach((x, t) => addStep(e, { ...fakeStep("ep1", t, [0, 0], [0]), ...x }));
  return e;
}

test("the panel says who acts at the shown step, and the alarm with its reason", () => {
  const before = renderToStaticMarkup(<TakeoverPanel episode={episode("alarm")} index={1} length={60} />);
  expect(before).toContain('data-who="policy"');
  expect(before).toContain("POLICY ACTING");
  expect(before).toContain("Alarms (1)");
  expect(before).toContain("step 1: <strong>stall</strong> no subgoal done for 4 steps (next: grasp a)");
  expect(before).toContain("atoms grasp a");
  const during = renderToStaticMarkup(<TakeoverPanel episode={episode("alarm")} index={3} length={60} />);
  expect(during).toContain('data-who="expert"');
  expect(during).toContain("EXPERT ACTING");
  expect(during).toContain("takeover 1, action 2 of 60 since step 2 (stall: no subgoal done");
  expect(during).toContain("1 takeover so far, 2 actions by the expert");
});

test("nothing is shown for an episode without takeovers", () => {
  const e = newEpisode(fakeStart("ep2"));
  addStep(e, fakeStep("ep2", 0, [0, 0], [0]));
  expect(renderToStaticMarkup(<TakeoverPanel episode={e} index={0} length={null} />)).toBe("");
});
