import { expect, test } from "vitest";
import { buildRaster, episodeFromRecord } from "./episode";
import { fakeStart, fakeStep } from "./fixtures";
import { HAS_TRUTH, PRED, TRUTH } from "./raster";

test("a recorded episode becomes bit vectors and a raster (atoms x steps)", () => {
  const steps = [fakeStep("r", 0, [0, 1], [0]), fakeStep("r", 1, [1, 1], [0], "IMG")];
  steps[1]!.truth = { object: [0, 1], action: [1] };
  steps[0]!.truth = null;
  const ep = episodeFromRecord({ start: fakeStart("r"), steps, end: null });
  expect(ep.atoms.map((a) => a.name)).toEqual(["on(a,b)", "left-of(a,b)", "grasped(a)"]);
  expect(ep.predicted).toEqual([
    [0, 1, 0],
    [1, 1, 0],
  ]);
  expect(ep.truth).toEqual([null, [0, 1, 1]]);
  expect(ep.steps[1]?.image).toBeNull();
  const r = buildRaster(ep);
  expect([r.numAtoms, r.numSteps]).toEqual([3, 2]);
  expect(r.get(0, 0)).toBe(0);
  expect(r.get(1, 0)).toBe(PRED);
  expect(r.get(0, 1)).toBe(PRED | HAS_TRUTH);
  expect(r.get(2, 1)).toBe(TRUTH | HAS_TRUTH);
  expect(r.activeRows()).toEqual([0, 1, 2]);
});
