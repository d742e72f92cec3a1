/**
 * The page's layout: skip links, the control bar, the stream banner, then camera, takeover and cognition (left) beside
 * the timeline and the beliefs (right), and the episodes list. The state lives in `useAppState`.
 */
import { Beliefs } from "./components/Beliefs";
import { Camera } from "./components/Camera";
import { Cognition } from "./components/Cognition";
import { ControlBar } from "./components/ControlBar";
import { Episodes } from "./components/Episodes";
import { Errors, StreamBanner } from "./components/StreamBanner";
import { TakeoverPanel } from "./components/Takeover";
import { Timeline } from "./components/Timeline";
import { DEFAULT_FADE_STEPS } from "./lib/flips";
import { caption } from "./lib/status";
import type { Store } from "./lib/store";
import { useAppState } from "./useAppState";
import { useThrottled } from "./useThrottled";

/** While following a live episode the beliefs (hundreds of rows) update at most 4 times a second. */
const LIVE_BELIEFS_MS = 250;

/** Moves the keyboard focus to an element (the link's own jump would only scroll). */
function focusOn(id: string) {
  return (e: React.MouseEvent) => {
    const el = document.getElementById(id);
    if (!el) return;
    e.preventDefault();
    el.focus();
    el.scrollIntoView({ block: "nearest" });
  };
}

function SkipLinks() {
  return (
    <nav className="skip" aria-label="skip links">
      <a href="#timeline" data-testid="skip-timeline" onClick={focusOn("timeline-slider")}>
        Skip to the timeline
      </a>
      <a href="#beliefs" onClick={focusOn("beliefs")}>
        Skip to the beliefs
      </a>
    </nav>
  );
}

export function App({ store }: { store: Store }) {
  const s = useAppState(store);
  const { snap, episode, index } = s;
  const n = episode?.steps.length ?? 0;
  const beliefIndex = useThrottled(index, s.following ? LIVE_BELIEFS_MS : 0);
  return (
    <div className="app">
      <SkipLinks />
      <ControlBar state={s} />
      <StreamBanner state={s} onClose={() => store.closeReplay()} />
      <Errors errors={snap.errors} onDismiss={() => store.dismissErrors()} />
      <main className="grid" id="main">
        <div className="left">
          <Camera
            src={s.src}
            fps={s.following || s.running ? snap.fps : null}
            caption={caption(episode, index, s.paused && !snap.replay)}
            step={episode?.steps[index] ?? null}
          />
          {episode && (
            <TakeoverPanel
              episode={episode}
              index={index}
              length={snap.hello?.takeover?.steps ?? null}
              until={snap.hello?.takeover?.until ?? "steps"}
            />
          )}
          {episode && <Cognition episode={episode} index={index} />}
        </div>
        <div className="right">
          {episode && n > 0 && (
            <Timeline
              episode={episode}
              index={index}
              onSeek={s.seekTo}
              playing={s.playing}
              onPlay={s.setPlaying}
              live={s.running && !snap.replay}
              following={s.following}
              onBackToLive={s.backToLive}
            />
          )}
          {episode ? (
            <Beliefs episode={episode} index={Math.min(beliefIndex, n - 1)} fadeSteps={DEFAULT_FADE_STEPS} />
          ) : (
            <section className="panel" aria-labelledby="beliefs-h" id="beliefs">
              <h2 id="beliefs-h">Beliefs</h2>
              <p className="muted">{snap.hello ? `model ${snap.hello.model_id}` : "connecting to the server…"}</p>
            </section>
          )}
        </div>
      </main>
      <aside aria-label="episodes list">
        <Episodes state={s} />
      </aside>
    </div>
  );
}
