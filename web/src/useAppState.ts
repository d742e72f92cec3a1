/**
 * The page's state and actions: the connection feeding the store, the episodes list, the timeline's slider
 * (following the live episode or held where the user put it), playback, and the commands to the server.
 */
import { useCallback, useEffect, useRef, useState, useSyncExternalStore } from "react";
import { fetchEpisode, fetchEpisodes, frameUrl, wsUrl } from "./lib/api";
import { Connection, type SocketLike } from "./lib/connection";
import type { EpisodeData } from "./lib/episode";
import { frameKey } from "./lib/imageCache";
import { type SliderState, onStepsChanged, seek } from "./lib/slider";
import { type Snapshot, type Store, isPaused } from "./lib/store";
import { type ClientMessage, type EpisodeListItem, parseServerMessage } from "./messages";

export interface AppState {
  snap: Snapshot;
  /** The episode shown: an opened one, else the live one. */
  episode: EpisodeData | null;
  /** Step index shown. */
  index: number;
  /** The slider follows the newest step of a running episode. */
  following: boolean;
  running: boolean;
  paused: boolean;
  playing: boolean;
  /** Image of the shown step (live frame, cached frame or the server's URL). */
  src: string | null;
  episodes: EpisodeListItem[];
  listError: string | null;
  /** A drop was sent and no perturbed step came back yet. */
  dropRequested: boolean;
  send: (msg: ClientMessage) => void;
  seekTo: (index: number) => void;
  backToLive: () => void;
  setPlaying: (play: boolean) => void;
  openEpisode: (id: string, play: boolean) => void;
  rerunEpisode: (id: string) => void;
  refresh: () => void;
}

function useConnection(store: Store): (msg: ClientMessage) => boolean {
  const connection = useRef<Connection | null>(null);
  useEffect(() => {
    const conn = new Connection(() => new WebSocket(wsUrl()) as unknown as SocketLike, {
      onMessage: (text) => {
        const msg = parseServerMessage(text);
        if (msg) store.handle(msg);
      },
      onState: (state, retry) => store.setConnection(state, retry),
    });
    connection.current = conn;
    conn.connect();
    const fps = window.setInterval(() => store.refreshFps(), 1000);
    return () => {
      window.clearInterval(fps);
      conn.dispose();
    };
  }, [store]);
  return useCallback((msg: ClientMessage) => connection.current?.send(msg) ?? false, []);
}

function useEpisodeList(snap: Snapshot): Pick<AppState, "episodes" | "listError" | "refresh"> {
  const [episodes, setEpisodes] = useState<EpisodeListItem[]>([]);
  const [listError, setListError] = useState<string | null>(null);
  const refresh = useCallback(() => {
    fetchEpisodes()
      .then((list) => {
        setEpisodes(list);
        setListError(null);
      })
      .catch((e: unknown) => setListError(String(e)));
  }, []);
  const liveEnded = snap.live?.end != null;
  useEffect(() => {
    if (snap.hello) refresh();
  }, [snap.hello, liveEnded, snap.live?.id, refresh]);
  return { episodes, listError, refresh };
}

/** The slider and playback over the shown episode. */
function useSlider(snap: Snapshot, episode: EpisodeData | null, autoplay: React.RefObject<boolean>) {
  const [slider, setSlider] = useState<SliderState>({ index: 0, follow: true });
  const [playing, setPlaying] = useState(false);
  const n = episode?.steps.length ?? 0;
  const episodeKey = episode ? `${snap.replay ? "replay" : "live"}:${episode.id}` : "";
  useEffect(() => {
    setSlider({ index: 0, follow: !snap.replay });
    setPlaying(autoplay.current);
    autoplay.current = false;
  }, [episodeKey]); // only when another episode is shown
  const view = onStepsChanged(slider, n);
  const index = view.index;
  const hz = snap.hello?.image_hz || 10;
  useEffect(() => {
    if (!playing) return;
    if (index >= n - 1) {
      setPlaying(false);
      return;
    }
    const timer = window.setTimeout(() => setSlider((s) => seek(s, index + 1, n)), 1000 / hz);
    return () => window.clearTimeout(timer);
  }, [playing, index, n, hz]);
  const seekTo = useCallback((i: number) => setSlider((s) => seek(s, i, n)), [n]);
  const backToLive = useCallback(() => setSlider({ index: Math.max(0, n - 1), follow: true }), [n]);
  const play = useCallback(
    (on: boolean) => {
      if (on && index >= n - 1) setSlider((s) => seek(s, 0, n));
      setPlaying(on);
    },
    [index, n],
  );
  return { index, follow: view.follow, playing, seekTo, backToLive, setPlaying: play, setSlider };
}

export function useAppState(store: Store): AppState {
  const snap = useSyncExternalStore(store.subscribe, store.getSnapshot);
  const sendRaw = useConnection(store);
  const list = useEpisodeList(snap);
  const autoplay = useRef(false);
  const episode = snap.replay ?? snap.live;
  const slider = useSlider(snap, episode, autoplay);
  const [dropAt, setDropAt] = useState<number | null>(null);

  const send = useCallback(
    (msg: ClientMessage) => {
      if (!sendRaw(msg)) store.addError("not connected: the command was not sent");
      else if (msg.type === "drop") setDropAt(snap.live?.steps.length ?? 0);
    },
    [store, sendRaw, snap.live],
  );
  const openEpisode = useCallback(
    (id: string, play: boolean) => {
      fetchEpisode(id)
        .then((record) => {
          autoplay.current = play;
          store.loadReplay(record);
          slider.setSlider({ index: 0, follow: false });
          slider.setPlaying(play);
        })
        .catch((e: unknown) => store.addError(String(e)));
    },
    [store, slider.setSlider, slider.setPlaying],
  );
  const rerunEpisode = useCallback((id: string) => send({ type: "replay", episode_id: id, hz: null }), [send]);

  const running = !!snap.live && !snap.live.end;
  const live = snap.live;
  const perturbedSince = dropAt !== null && live ? live.steps.slice(dropAt).some((s) => s.perturbed) : false;
  const dropRequested = running && dropAt !== null && !perturbedSince;
  const following = !snap.replay && running && slider.follow;
  const step = episode?.steps[slider.index];
  let src: string | null = null;
  if (following) src = snap.frame;
  else if (episode && step) src = store.images.get(frameKey(episode.id, step.t)) ?? frameUrl(episode.start.store_episode ?? episode.id, step.t);
  return {
    snap,
    episode,
    index: slider.index,
    following,
    running,
    paused: isPaused(snap),
    playing: slider.playing,
    src,
    ...list,
    dropRequested,
    send,
    seekTo: slider.seekTo,
    backToLive: slider.backToLive,
    setPlaying: slider.setPlaying,
    openEpisode,
    rerunEpisode,
  };
}
