import { describe, expect, test } from "vitest";
import { atomViewsAt, passesFilter } from "./flips";

const series = [
  [0, 1, 0],
  [1, 1, 0],
  [1, 0, 0],
  [1, 0, 0],
  [1, 0, 0],
  [1, 0, 0],
  [1, 0, 0],
];
const at = (j: number) => series[j] ?? [];

describe("atomViewsAt", () => {
  test("first step has no flips", () => {
    expect(atomViewsAt(at, 0, 3).map((v) => v.state)).toEqual(["off", "on", "off"]);
  });
  test("a flip to true is turned-on, to false turned-off, at full strength", () => {
    const views = atomViewsAt(at, 1, 3);
    expect(views[0]).toEqual({ value: 1, state: "turned-on", age: 0, fade: 1 });
    expect(atomViewsAt(at, 2, 3)[1]).toEqual({ value: 0, state: "turned-off", age: 0, fade: 1 });
  });
  test("the highlight fades over fadeSteps steps, then the atom is plain on", () => {
    expect(atomViewsAt(at, 2, 3)[0]).toMatchObject({ state: "turned-on", age: 1 });
    expect(atomViewsAt(at, 2, 3)[0]?.fade).toBeCloseTo(2 / 3);
    expect(atomViewsAt(at, 3, 3)[0]).toMatchObject({ state: "turned-on", age: 2 });
    expect(atomViewsAt(at, 4, 3)[0]).toMatchObject({ state: "on", age: Infinity, fade: 0 });
    expect(atomViewsAt(at, 6, 3)[1]).toMatchObject({ state: "off" });
  });
  test("only the last flip counts", () => {
    const s = [[0], [1], [0]];
    expect(atomViewsAt((j) => s[j] ?? [], 2, 5)[0]).toMatchObject({ state: "turned-off", age: 0 });
  });
  test("filters", () => {
    const views = atomViewsAt(at, 2, 3);
    expect(views.filter((v) => passesFilter(v, "true")).length).toBe(1);
    expect(views.filter((v) => passesFilter(v, "changed")).map((v) => v.value)).toEqual([0]);
    expect(views.filter((v) => passesFilter(v, "all")).length).toBe(3);
  });
});
