/** One episode as the UI holds it: its start, its steps (images stripped), bit vectors, and its end. */
import type { EpisodeEnd, EpisodeRecord, EpisodeStart, Step } from "../messages";
import { type AtomInfo, atomInfos, predictedBits, truthBits } from "./atoms";
import { Raster } from "./raster";

export interface EpisodeData {
  id: string;
  start: EpisodeStart;
  atoms: AtomInfo[];
  /** Scored atoms: probed and defined in the episode. */
  probed: boolean[];
  /** Steps in arrival order, without their images. */
  steps: Step[];
  /** Predicted values of each step, object then action. */
  predicted: number[][];
  /** True values of each step, or null where not streamed. */
  truth: (number[] | null)[];
  end: EpisodeEnd | null;
}

export function newEpisode(start: EpisodeStart): EpisodeData {
  const atoms = atomInfos(start);
  return {
    id: start.episode_id,
    start,
    atoms,
    probed: atoms.map((a) => a.probed && a.defined),
    steps: [],
    predicted: [],
    truth: [],
    end: null,
  };
}

/** Appends a step (its image, if any, is dropped here: images live in the bounded cache). */
export function addStep(episode: EpisodeData, step: Step): void {
  const stripped: Step = { ...step, image: null };
  episode.steps.push(stripped);
  episode.predicted.push(predictedBits(step));
  episode.truth.push(truthBits(step));
}

export function episodeFromRecord(record: EpisodeRecord): EpisodeData {
  const episode = newEpisode(record.start);
  for (const step of record.steps) addStep(episode, step);
  episode.end = record.end;
  return episode;
}

/** The atoms x steps raster of the episode's first `count` steps (default: all). */
export function buildRaster(episode: EpisodeData, count: number = episode.steps.length): Raster {
  const n = Math.min(count, episode.steps.length);
  const raster = new Raster(episode.atoms.length, n);
  for (let t = 0; t < n; t++) raster.setStep(t, episode.predicted[t] ?? [], episode.truth[t] ?? null);
  return raster;
}
