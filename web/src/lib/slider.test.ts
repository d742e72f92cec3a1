import { expect, test } from "vitest";
import { clampStep, onStepsChanged, seek, stepForKey } from "./slider";

test("clamp", () => {
  expect(clampStep(-3, 10)).toBe(0);
  expect(clampStep(12, 10)).toBe(9);
  expect(clampStep(4.6, 10)).toBe(5);
  expect(clampStep(3, 0)).toBe(0);
});

test("following tracks the newest step; a seek stops following until the end is reached", () => {
  let s = { index: 0, follow: true };
  s = onStepsChanged(s, 5);
  expect(s).toEqual({ index: 4, follow: true });
  s = seek(s, 2, 5);
  expect(s).toEqual({ index: 2, follow: false });
  s = onStepsChanged(s, 8);
  expect(s.index).toBe(2);
  expect(seek({ index: 2, follow: true }, 7, 8)).toEqual({ index: 7, follow: true });
});

test("keys", () => {
  expect(stepForKey("ArrowRight", 3, 10)).toBe(4);
  expect(stepForKey("ArrowLeft", 0, 10)).toBe(0);
  expect(stepForKey("PageUp", 3, 10)).toBe(9);
  expect(stepForKey("PageDown", 13, 20)).toBe(3);
  expect(stepForKey("Home", 5, 10)).toBe(0);
  expect(stepForKey("End", 5, 10)).toBe(9);
  expect(stepForKey("a", 5, 10)).toBeNull();
});
