import { expect, test } from "vitest";
import { atomInfos } from "./atoms";
import { beliefGroups, beliefRows, episodeObjects } from "./beliefRows";
import { addStep, newEpisode } from "./episode";
import { fakeStart, fakeStep } from "./fixtures";
import { type BeliefRow, agesAt, argsOf, compareRows, focusedSections, isPinned, taskObjects, timelineRows } from "./focus";

const row = (over: Partial<BeliefRow>): BeliefRow => ({
  index: 0,
  name: "on(a,b)",
  pinned: false,
  probed: true,
  value: 0,
  state: "off",
  age: Infinity,
  truth: 0,
  worldAge: Infinity,
  disagree: false,
  prob: 0.1,
  ...over,
});

test("task objects: the server's goal objects, else the instruction's nouns; pinned atoms mention them", () => {
  const atoms = atomInfos(fakeStart("e", ["on(akita_black_bowl_1,plate_1)", "left-of(cookies_1,ramekin_1)"], ["grasped(plate_1)"]));
  expect(argsOf("left-of(a, b)")).toEqual(["a", "b"]);
  expect(argsOf("odd")).toEqual([]);
  expect([...taskObjects(["akita_black_bowl_1"], "", atoms)]).toEqual(["akita_black_bowl_1"]);
  expect([...taskObjects([], "pick up the black bowl and place it on the plate", atoms)].sort()).toEqual([
    "akita_black_bowl_1",
    "plate_1",
  ]);
  const objects = new Set(["akita_black_bowl_1"]);
  expect(atoms.map((a) => isPinned(a, objects))).toEqual([true, false, true]); // action atoms always
});

test("sections: disagreements first, then the vector order; filters; unprobed hidden and counted", () => {
  const rows = [
    row({ index: 0, pinned: true, value: 1 }),
    row({ index: 1, pinned: true, disagree: true, value: 1, truth: 0 }),
    row({ index: 2, pinned: false, age: 2 }),
    row({ index: 3, pinned: false, worldAge: 0, disagree: true, truth: 1 }),
    row({ index: 4, pinned: true, probed: false, value: 1 }),
    row({ index: 5, pinned: false, probed: false, age: 0 }),
    row({ index: 6, pinned: true, age: 1 }),
  ];
  const all = focusedSections(rows, { filter: "all", showUnprobed: false, window: 5 });
  expect(all.pinned.map((r) => r.index)).toEqual([1, 0, 6]);
  expect(all.other.map((r) => r.index)).toEqual([3, 2]);
  expect(all.hiddenUnprobed).toBe(2);
  const disagree = focusedSections(rows, { filter: "disagree", showUnprobed: false, window: 5 });
  expect([...disagree.pinned, ...disagree.other].map((r) => r.index)).toEqual([1, 3]);
  expect(disagree.hiddenUnprobed).toBe(0); // unprobed atoms never disagree
  const changedRows = focusedSections(rows, { filter: "changed", showUnprobed: true, window: 5 });
  expect(changedRows.pinned.map((r) => r.index)).toEqual([6]);
  expect(changedRows.other.map((r) => r.index)).toEqual([3, 2, 5]); // a world change counts too
  expect(focusedSections(rows, { filter: "changed", showUnprobed: true, window: 2 }).other.map((r) => r.index)).toEqual([3, 5]); // age 2 is out
  const trueRows = focusedSections(rows, { filter: "true", showUnprobed: true, window: 5 });
  expect(trueRows.pinned.map((r) => r.index)).toEqual([1, 0, 4]);
  expect(compareRows(rows[3]!, rows[0]!)).toBeLessThan(0); // a disagreement sorts before an agreeing atom
  expect(compareRows(rows[0]!, rows[0]!)).toBe(0);
});

test("ages: steps since each value changed, within the window", () => {
  const bits = [[0, 0, 1], [1, 0, 1], [1, 0, 0], [1, 0, 0]];
  expect(agesAt((j) => bits[j] ?? null, 3, 5)).toEqual([2, Infinity, 1]);
  expect(agesAt((j) => bits[j] ?? null, 3, 1)).toEqual([Infinity, Infinity, Infinity]);
  expect(agesAt(() => null, 0, 5)).toEqual([]);
});

test("belief rows of an episode step: prediction vs world, world flips, pinned by goal objects", () => {
  const start = fakeStart("e", ["on(a,b)", "left-of(c,d)"], ["grasped(a)"]);
  start.goal_objects = ["a"];
  const ep = newEpisode(start);
  const s0 = fakeStep("e", 0, [0, 0], [0]);
  const s1 = fakeStep("e", 1, [1, 0], [0]);
  s1.truth = { object: [0, 1], action: [0] };
  addStep(ep, s0);
  addStep(ep, s1);
  const rows = beliefRows(ep, 1, 5, episodeObjects(ep));
  expect(rows.map((r) => [r.name, r.pinned, r.value, r.truth, r.disagree, r.age, r.worldAge])).toEqual([
    ["on(a,b)", true, 1, 0, true, 0, Infinity],
    ["left-of(c,d)", false, 0, 1, true, Infinity, 0],
    ["grasped(a)", true, 0, 0, false, Infinity, Infinity],
  ]);
  expect(beliefRows(ep, 5, 5, new Set())).toEqual([]);
});

test("an atom the episode leaves undefined: no belief row, never scored", () => {
  const start = fakeStart("e", ["on(a,b)", "on(x,b)"], ["grasped(a)"]);
  start.defined = { object: [true, false], action: [true] };
  const ep = newEpisode(start);
  const s0 = fakeStep("e", 0, [1, 0], [0]);
  s0.truth = { object: [0, 0], action: [0] };
  addStep(ep, s0);
  expect(ep.atoms.map((a) => a.defined)).toEqual([true, false, true]);
  expect(ep.probed).toEqual([true, false, true]);
  expect(beliefRows(ep, 0, 5, new Set()).map((r) => r.name)).toEqual(["on(a,b)", "grasped(a)"]);
  expect(atomInfos(fakeStart("e", ["on(a,b)"], [])).map((a) => a.defined)).toEqual([true]); // protocol < 3
});

test("timeline rows leave out the atoms the episode leaves undefined, pinned action atoms included", () => {
  const start = fakeStart("e", ["on(a,b)", "on(x,b)", "left-of(a,b)"], ["grasped(a)", "grasped(x)"]);
  start.defined = { object: [true, false, true], action: [true, false] };
  const atoms = atomInfos(start);
  expect(timelineRows([0, 1, 2], atoms, new Set(["a"]))).toEqual({ rows: [0, 2, 3], pinned: 3 });
  expect(timelineRows([1], atoms, new Set())).toEqual({ rows: [3], pinned: 1 });
});

test("belief groups: rows found by atom index when undefined atoms are left out", () => {
  const start = fakeStart("e", ["on(x,b)", "on(a,b)", "left-of(a,b)"], ["grasped(a)"]);
  start.defined = { object: [false, true, true], action: [true] };
  const ep = newEpisode(start);
  addStep(ep, fakeStep("e", 0, [0, 1, 0], [1]));
  const groups = beliefGroups(ep.atoms, beliefRows(ep, 0, 5, new Set()));
  expect(groups.map((g) => [g.predicate, g.rows.map((r) => [r.name, r.value])])).toEqual([
    ["on", [["on(a,b)", 1]]],
    ["left-of", [["left-of(a,b)", 0]]],
    ["grasped", [["grasped(a)", 1]]],
  ]);
});

test("timeline rows: task-relevant first (action atoms always), then the other active atoms", () => {
  const atoms = atomInfos(fakeStart("e", ["on(x,y)", "on(a,b)", "left-of(a,c)"], ["grasped(a)", "grasped(x)"]));
  expect(timelineRows([0, 2], atoms, new Set(["a"]))).toEqual({ rows: [2, 3, 4, 0], pinned: 3 });
});
