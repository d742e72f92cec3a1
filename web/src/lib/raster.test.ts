import { expect, test } from "vitest";
import { HAS_TRUTH, PRED, Raster, TRUTH, cellAtPoint, cellKind, stepAtX, tickEvery } from "./raster";

test("cells are indexed by atom then step", () => {
  const r = new Raster(3, 4);
  r.setStep(2, [1, 0, 0], [1, 1, 0]);
  expect(r.index(1, 2)).toBe(6);
  expect(r.get(0, 2)).toBe(PRED | TRUTH | HAS_TRUTH);
  expect(r.get(1, 2)).toBe(TRUTH | HAS_TRUTH);
  expect(r.get(2, 2)).toBe(HAS_TRUTH);
  expect(r.get(0, 1)).toBe(0);
  r.setStep(3, [0, 0, 1], null);
  expect(r.get(2, 3)).toBe(PRED);
  expect(r.activeRows()).toEqual([0, 1, 2]);
  expect(new Raster(2, 2).activeRows()).toEqual([]);
});

test("cell kinds mark disagreements", () => {
  expect(cellKind(PRED | TRUTH | HAS_TRUTH)).toBe("on");
  expect(cellKind(HAS_TRUTH)).toBe("off");
  expect(cellKind(PRED | HAS_TRUTH)).toBe("false-alarm");
  expect(cellKind(TRUTH | HAS_TRUTH)).toBe("missed");
  expect(cellKind(PRED)).toBe("on");
  expect(cellKind(0)).toBe("off");
});

test("a click maps to the cell under it", () => {
  const layout = { left: 100, top: 10, cellWidth: 3, cellHeight: 6, rows: [4, 7, 9], numSteps: 50 };
  expect(cellAtPoint(layout, 100, 10)).toEqual({ atom: 4, step: 0 });
  expect(cellAtPoint(layout, 105.9, 22)).toEqual({ atom: 9, step: 1 });
  expect(cellAtPoint(layout, 99, 12)).toBeNull();
  expect(cellAtPoint(layout, 100 + 3 * 50, 12)).toBeNull();
  expect(cellAtPoint(layout, 120, 10 + 6 * 3)).toBeNull();
});

test("axis ticks stay apart at any zoom; a column from x", () => {
  expect(tickEvery(16)).toBe(5);
  expect(tickEvery(3)).toBe(20);
  expect(tickEvery(0.5)).toBe(100);
  expect(stepAtX(4, 10, 9)).toBe(2);
  expect(stepAtX(4, 10, 40)).toBeNull();
  expect(stepAtX(4, 10, -1)).toBeNull();
});
