import { expect, test } from "vitest";
import { atomInfos, groupByPredicate, predicateOf, predictedBits, truthBits } from "./atoms";
import { fakeStart, fakeStep } from "./fixtures";
import { parseServerMessage } from "../messages";

test("atoms in vector order, object head first, grouped by predicate in order of appearance", () => {
  const start = fakeStart("e", ["left-of(a,b)", "on(a,b)", "left-of(b,a)"], ["grasped(a)"]);
  start.probed.object[1] = false;
  const atoms = atomInfos(start);
  expect(atoms.map((a) => [a.index, a.name, a.head, a.probed])).toEqual([
    [0, "left-of(a,b)", "object", true],
    [1, "on(a,b)", "object", false],
    [2, "left-of(b,a)", "object", true],
    [3, "grasped(a)", "action", true],
  ]);
  expect(groupByPredicate(atoms).map((g) => [g.head, g.predicate, g.atoms.map((a) => a.index)])).toEqual([
    ["object", "left-of", [0, 2]],
    ["object", "on", [1]],
    ["action", "grasped", [3]],
  ]);
  expect(predicateOf("should-move-towards(a)")).toBe("should-move-towards");
  expect(predicateOf("odd")).toBe("odd");
});

test("bit vectors concatenate the heads; no truth is null", () => {
  const step = fakeStep("e", 0, [1, 0], [1]);
  expect(predictedBits(step)).toEqual([1, 0, 1]);
  expect(truthBits(step)).toEqual([1, 0, 1]);
  expect(truthBits({ truth: null })).toBeNull();
});

test("server frames: known types parse, anything else is ignored", () => {
  expect(parseServerMessage('{"type":"error","message":"x"}')).toEqual({ type: "error", message: "x" });
  expect(parseServerMessage("{")).toBeNull();
  expect(parseServerMessage('{"type":"nope"}')).toBeNull();
  expect(parseServerMessage("[1]")).toBeNull();
  expect(parseServerMessage("null")).toBeNull();
});
