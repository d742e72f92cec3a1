/** The belief rows of one step of an episode (prediction, world, flips, probability, pinned). */
import { atomAgreement } from "./agreement";
import { type AtomInfo, type Head, groupByPredicate } from "./atoms";
import type { EpisodeData } from "./episode";
import { atomViewsAt } from "./flips";
import { type BeliefRow, agesAt, isPinned, taskObjects } from "./focus";

/** The task's objects of an episode (pinned atoms mention them). */
export function episodeObjects(episode: EpisodeData): Set<string> {
  return taskObjects(episode.start.goal_objects, episode.start.instruction, episode.atoms);
}

export function beliefRows(episode: EpisodeData, index: number, window: number, objects: ReadonlySet<string>): BeliefRow[] {
  const predicted = episode.predicted[index];
  const step = episode.steps[index];
  if (!predicted || !step) return [];
  const truth = episode.truth[index] ?? null;
  const views = atomViewsAt((j) => episode.predicted[j] ?? [], index, window);
  const worldAges = truth ? agesAt((j) => episode.truth[j] ?? null, index, window) : [];
  const agreement = atomAgreement(predicted, truth, episode.probed);
  const probs = [...step.predicted.object.probs, ...step.predicted.action.probs];
  return episode.atoms.filter((a) => a.defined).map((a) => {
    const v = views[a.index];
    return {
      index: a.index,
      name: a.name,
      pinned: isPinned(a, objects),
      probed: a.probed,
      value: v?.value ?? 0,
      state: v?.state ?? "off",
      age: v?.age ?? Infinity,
      truth: truth ? (truth[a.index] ?? 0) : null,
      worldAge: worldAges[a.index] ?? Infinity,
      disagree: agreement[a.index] === "disagree",
      prob: probs[a.index] ?? null,
    };
  });
}

/** The belief rows of one predicate (the grouped view). */
export interface BeliefGroup {
  head: Head;
  predicate: string;
  rows: BeliefRow[];
}

/**
 * The rows grouped by predicate (the paper's order), over the atoms defined in the episode: rows are looked up by
 * atom index, since `beliefRows` leaves the undefined atoms out (a row's position is not its atom's index).
 */
export function beliefGroups(atoms: readonly AtomInfo[], rows: readonly BeliefRow[]): BeliefGroup[] {
  const byIndex = new Map(rows.map((r) => [r.index, r]));
  return groupByPredicate(atoms.filter((a) => a.defined)).map((g) => ({
    head: g.head,
    predicate: g.predicate,
    rows: g.atoms.map((a) => byIndex.get(a.index)).filter((r): r is BeliefRow => r !== undefined),
  }));
}
