import { expect, test } from "vitest";
import { actingAt, actingText, alarmText, alarmsUntil, takeoversUntil } from "./takeover";

const alarm = { kind: "violation" as const, reason: "on and inside", rules: ["on_inside"], atoms: ["on(a,b)", "inside(a,b)"] };
const tk = (steps: number) => ({ index: 1, start: 2, reason: "violation: on and inside", steps });
const steps = [
  { t: 0 },
  { t: 1, alarm },
  { t: 2, takeover: tk(1), handover: "to_expert" as const },
  { t: 3, takeover: tk(2) },
  { t: 4, handover: "to_policy" as const },
];

test("who acts: the expert under a takeover, else the policy", () => {
  expect(actingAt(steps, 0)).toEqual({ who: "policy", takeover: null });
  expect(actingAt(steps, 3)).toEqual({ who: "expert", takeover: tk(2) });
  expect(actingAt(steps, 4)?.who).toBe("policy");
  expect(actingAt(steps, 9)).toBeNull();
});

test("alarms up to the shown step, newest first, with rules and atoms in words", () => {
  expect(alarmsUntil(steps, 0)).toEqual([]);
  expect(alarmsUntil(steps, 4)).toEqual([{ index: 1, t: 1, alarm }]);
  expect(alarmText(alarm)).toBe("violation: on and inside · rules on_inside · atoms on(a,b), inside(a,b)");
});

test("takeovers up to the shown step, as of that step", () => {
  expect(takeoversUntil(steps, 1)).toEqual([]);
  expect(takeoversUntil(steps, 2)).toEqual([tk(1)]);
  expect(takeoversUntil(steps, 4)).toEqual([tk(2)]);
});

test("the acting line names the takeover, its progress and its reason", () => {
  expect(actingText({ who: "policy", takeover: null }, 60)).toBe("the policy acts");
  expect(actingText({ who: "expert", takeover: tk(2) }, 60)).toBe(
    "the scripted expert acts: takeover 1, action 2 of 60 since step 2 (violation: on and inside)",
  );
  expect(actingText({ who: "expert", takeover: tk(2) }, null)).toContain("action 2 since step 2");
  expect(actingText({ who: "expert", takeover: tk(2) }, 150, "subgoal")).toBe(
    "the scripted expert acts: takeover 1, action 2 of at most 150, until its subgoal is done, since step 2 (violation: on and inside)",
  );
});
