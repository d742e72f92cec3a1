import { expect, test } from "vitest";
import { agreementPercent, atomAgreement } from "./agreement";

test("per-atom agreement marks not-probed atoms and missing truth unknown", () => {
  expect(atomAgreement([1, 0, 1, 1], [1, 1, 0, 1], [true, true, true, false])).toEqual([
    "agree",
    "disagree",
    "disagree",
    "unknown",
  ]);
  expect(atomAgreement([1, 0], null, [true, true])).toEqual(["unknown", "unknown"]);
});

test("agreement percent counts probed atoms only", () => {
  expect(agreementPercent([1, 0, 1, 1], [1, 1, 1, 0], [true, true, true, false])).toBeCloseTo(200 / 3);
  expect(agreementPercent([1], null, [true])).toBeNull();
  expect(agreementPercent([1], [0], [false])).toBeNull();
  expect(agreementPercent([0, 0], [0, 0], [true, true])).toBe(100);
});
