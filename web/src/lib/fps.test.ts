import { expect, test } from "vitest";
import { FpsMeter } from "./fps";

test("measures the arrival rate over the window", () => {
  const m = new FpsMeter(1000);
  expect(m.fps(0)).toBe(0);
  for (let t = 0; t <= 900; t += 100) m.tick(t);
  expect(m.fps(900)).toBeCloseTo(10);
  expect(m.fps(5000)).toBe(0);
});
