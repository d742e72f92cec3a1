/**
 * The UI's state, fed by server messages: the hello, the live episode (steps appended in place, so a
 * 300-step episode costs O(1) per step), the replayed episode, the latest frame and the measured fps.
 * React reads it through `subscribe`/`getSnapshot` (useSyncExternalStore).
 */
import type { Hello, ServerMessage, EpisodeRecord } from "../messages";
import type { ConnectionState } from "./connection";
import { type EpisodeData, addStep, episodeFromRecord, newEpisode } from "./episode";
import { FpsMeter } from "./fps";
import { ImageCache, frameKey } from "./imageCache";

export interface Snapshot {
  connection: ConnectionState;
  retryInMs: number | null;
  hello: Hello | null;
  /** The current (or last) live episode. */
  live: EpisodeData | null;
  /** A recorded/stored episode loaded for replay; shown instead of `live` while set. */
  replay: EpisodeData | null;
  /** Id of the episode the server last said is paused (hello.running or a status message); null: none. */
  pausedEpisode: string | null;
  /** Data URL of the newest live frame. */
  frame: string | null;
  fps: number;
  errors: string[];
  /** Bumped on every change (steps are appended in place). */
  version: number;
}

const MAX_ERRORS = 5;

/** Whether the running live episode is paused, as the server last said (the same for every client). */
export function isPaused(snap: Snapshot): boolean {
  const { live, pausedEpisode } = snap;
  return live !== null && !live.end && live.id === pausedEpisode;
}

export class Store {
  readonly images: ImageCache;
  private readonly fpsMeter = new FpsMeter();
  private snapshot: Snapshot = {
    connection: "connecting",
    retryInMs: null,
    hello: null,
    live: null,
    replay: null,
    pausedEpisode: null,
    frame: null,
    fps: 0,
    errors: [],
    version: 0,
  };
  private readonly listeners = new Set<() => void>();

  constructor(
    images: ImageCache = new ImageCache(),
    private readonly now: () => number = () => performance.now(),
  ) {
    this.images = images;
  }

  subscribe = (listener: () => void): (() => void) => {
    this.listeners.add(listener);
    return () => this.listeners.delete(listener);
  };

  getSnapshot = (): Snapshot => this.snapshot;

  private update(patch: Partial<Snapshot>): void {
    this.snapshot = { ...this.snapshot, ...patch, version: this.snapshot.version + 1 };
    for (const listener of this.listeners) listener();
  }

  setConnection(connection: ConnectionState, retryInMs: number | null): void {
    this.update({ connection, retryInMs });
  }

  addError(message: string): void {
    this.update({ errors: [...this.snapshot.errors, message].slice(-MAX_ERRORS) });
  }

  dismissErrors(): void {
    this.update({ errors: [] });
  }

  handle(msg: ServerMessage): void {
    switch (msg.type) {
      case "hello":
        // A (re)connection: errors about the old connection or episode are stale.
        this.update({ hello: msg, pausedEpisode: msg.running?.paused ? msg.running.episode_id : null, errors: [] });
        return;
      case "status":
        this.update({ pausedEpisode: msg.paused ? msg.episode_id : null });
        return;
      case "episode_start":
        this.update({ live: newEpisode(msg), replay: null, frame: null, errors: [] });
        return;
      case "history": {
        const live = newEpisode(msg.start);
        for (const step of msg.steps) addStep(live, step);
        this.update({ live, replay: null, errors: [] });
        return;
      }
      case "step": {
        const live = this.snapshot.live;
        if (!live || live.id !== msg.episode_id) return;
        addStep(live, msg);
        if (msg.image) {
          const url = `data:image/jpeg;base64,${msg.image}`;
          this.images.set(frameKey(live.id, msg.t), url);
          this.fpsMeter.tick(this.now());
          this.update({ frame: url, fps: this.fpsMeter.fps(this.now()) });
        } else {
          this.update({});
        }
        return;
      }
      case "episode_end": {
        const live = this.snapshot.live;
        if (live && live.id === msg.episode_id) {
          live.end = msg;
          this.update({});
        }
        return;
      }
      case "error":
        this.addError(msg.message);
        return;
    }
  }

  /** Shows a recorded or stored episode (from GET /api/episodes/{id}). */
  loadReplay(record: EpisodeRecord): void {
    this.update({ replay: episodeFromRecord(record) });
  }

  closeReplay(): void {
    this.update({ replay: null });
  }

  /** Current fps (decays to 0 when frames stop). */
  refreshFps(): void {
    const fps = this.fpsMeter.fps(this.now());
    if (fps !== this.snapshot.fps) this.update({ fps });
  }
}
