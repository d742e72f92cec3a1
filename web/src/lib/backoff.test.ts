import { expect, test } from "vitest";
import { backoffDelay } from "./backoff";

const cfg = { baseMs: 100, maxMs: 1000, factor: 2, jitter: 0.2 };

test("doubles per attempt up to the cap", () => {
  expect([0, 1, 2, 3, 4, 10].map((a) => backoffDelay(a, cfg, 0.5))).toEqual([100, 200, 400, 800, 1000, 1000]);
});

test("jitter stays within its fraction and under the cap", () => {
  expect(backoffDelay(1, cfg, 0)).toBe(160);
  expect(backoffDelay(1, cfg, 0.999)).toBeLessThanOrEqual(240);
  expect(backoffDelay(9, cfg, 0.999)).toBe(1000);
});
