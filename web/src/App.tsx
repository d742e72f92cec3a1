/** The page: control bar on top; camera, beliefs and cognition; the timeline once an episode ends or is opened; the episodes list. */
import { useCallback, useEffect, useRef, useState, useSyncExternalStore } from "react";
import { Beliefs } from "./components/Beliefs";
import { Camera } from "./components/Camera";
import { Cognition } from "./components/Cognition";
import { ControlBar } from "./components/ControlBar";
import { Episodes } from "./components/Episodes";
import { Timeline } from "./components/Timeline";
import { fetchEpisode, fetchEpisodes, frameUrl, wsUrl } from "./lib/api";
import { Connection, type SocketLike } from "./lib/connection";
import { DEFAULT_FADE_STEPS } from "./lib/flips";
import { frameKey } from "./lib/imageCache";
import { type SliderState, onStepsChanged, seek } from "./lib/slider";
import { type Store, isPaused } from "./lib/store";
import { type ClientMessage, type EpisodeListItem, parseServerMessage } from "./messages";

export function App({ store }: { store: Store }) {
  const snap = useSyncExternalStore(store.subscribe, store.getSnapshot);
  const connection = useRef<Connection | null>(null);
  const [episodes, setEpisodes] = useState<EpisodeListItem[]>([]);
  const [listError, setListError] = useState<string | null>(null);
  const [slider, setSlider] = useState<SliderState>({ index: 0, follow: true });
  const [playing, setPlaying] = useState(false);
  const [missing, setMissing] = useState<string | null>(null);
  const autoplay = useRef(false);

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

  const send = useCallback(
    (msg: ClientMessage) => {
      if (!connection.current?.send(msg)) store.addError("not connected: the command was not sent");
    },
    [store],
  );

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

  const episode = snap.replay ?? snap.live;
  const n = episode?.steps.length ?? 0;
  const episodeKey = episode ? `${snap.replay ? "replay" : "live"}:${episode.id}` : "";
  useEffect(() => {
    setSlider({ index: 0, follow: !snap.replay });
    setPlaying(autoplay.current);
    autoplay.current = false;
  }, [episodeKey]); // only when another episode is shown
  const view = onStepsChanged(slider, n);
  const index = view.index;

  // Playing: one step per tick at the stream's rate, stopping at the last step.
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

  const onSeek = useCallback((i: number) => setSlider((s) => seek(s, i, n)), [n]);
  const onPlay = useCallback(
    (play: boolean) => {
      if (play && index >= n - 1) setSlider((s) => seek(s, 0, n));
      setPlaying(play);
    },
    [index, n],
  );
  const openEpisode = useCallback(
    (id: string, play: boolean) => {
      fetchEpisode(id)
        .then((record) => {
          autoplay.current = play;
          store.loadReplay(record);
          setSlider({ index: 0, follow: false });
          setPlaying(play);
        })
        .catch((e: unknown) => store.addError(String(e)));
    },
    [store],
  );
  const streamEpisode = useCallback((id: string) => send({ type: "replay", episode_id: id, hz: null }), [send]);

  const running = !!snap.live && !snap.live.end;
  const paused = isPaused(snap);
  const reviewing = !!episode && (!!snap.replay || !!episode.end);
  const step = episode?.steps[index];
  const following = !snap.replay && running && view.follow;
  let src: string | null = null;
  if (following) src = snap.frame;
  else if (episode && step) src = store.images.get(frameKey(episode.id, step.t)) ?? frameUrl(episode.id, step.t);
  const caption = step
    ? `${episode?.start.instruction} · ${step.status}${episode?.end ? ` · ${episode.end.success ? "success" : episode.end.stopped ? "stopped" : "failed"}` : ""}${paused && !snap.replay ? " · paused" : ""}`
    : episode
      ? `${episode.start.instruction} · starting…`
      : "no episode yet: pick a task and start";

  return (
    <div className="app">
      <ControlBar
        hello={snap.hello}
        connection={snap.connection}
        retryInMs={snap.retryInMs}
        running={running}
        paused={paused}
        send={send}
      />
      {snap.errors.length > 0 && (
        <div className="errors" role="alert" data-testid="errors">
          {snap.errors.map((e, i) => (
            <div key={i}>⚠ {e}</div>
          ))}
          <button onClick={() => store.dismissErrors()}>dismiss</button>
        </div>
      )}
      {snap.replay && (
        <div className="banner">
          Viewing the {snap.replay.start.source === "store" ? "stored" : "recorded"} episode {snap.replay.id}{" "}
          <button data-testid="back-to-live" onClick={() => store.closeReplay()}>
            back to live
          </button>
        </div>
      )}
      <main className="grid">
        <div className="left">
          <Camera
            src={src && missing !== src ? src : null}
            fps={following || running ? snap.fps : null}
            caption={caption}
            onMissing={() => setMissing(src)}
          />
          {episode && <Cognition episode={episode} index={index} />}
          <Episodes
            episodes={episodes}
            error={listError}
            selected={snap.replay?.id ?? null}
            onOpen={openEpisode}
            onStream={streamEpisode}
            onRefresh={refresh}
          />
        </div>
        <div className="right">
          {episode && reviewing && n > 0 && (
            <Timeline episode={episode} index={index} onSeek={onSeek} playing={playing} onPlay={onPlay} />
          )}
          {episode ? (
            <Beliefs episode={episode} index={index} fadeSteps={DEFAULT_FADE_STEPS} />
          ) : (
            <section className="panel">
              <h2>Beliefs</h2>
              <p className="muted">{snap.hello ? `model ${snap.hello.model_id}` : "connecting to the server…"}</p>
            </section>
          )}
        </div>
      </main>
    </div>
  );
}
