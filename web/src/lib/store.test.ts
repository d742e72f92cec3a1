import { expect, test } from "vitest";
import { ImageCache } from "./imageCache";
import { Store, isPaused } from "./store";
import { fakeStart, fakeStep } from "./fixtures";

test("a live episode: steps appended, images cached without being kept on steps, end recorded", () => {
  let now = 0;
  const store = new Store(new ImageCache(2), () => now);
  let notified = 0;
  store.subscribe(() => notified++);
  store.handle(fakeStart("e"));
  for (let t = 0; t < 5; t++) {
    now = t * 100;
    store.handle(fakeStep("e", t, [t % 2, 0], [1], `IMG${t}`));
  }
  store.handle(fakeStep("other", 9, [1, 1], [1]));
  const s = store.getSnapshot();
  expect(s.live?.steps.length).toBe(5);
  expect(s.live?.steps.every((st) => st.image === null)).toBe(true);
  expect(s.live?.predicted[3]).toEqual([1, 0, 1]);
  expect(s.frame).toBe("data:image/jpeg;base64,IMG4");
  expect(s.fps).toBeCloseTo(10);
  expect(store.images.size).toBe(2);
  store.handle({
    type: "episode_end",
    episode_id: "e",
    success: true,
    steps: 5,
    stopped: false,
    summary: { violations: {}, goal_step_predicted: 3, goal_step_truth: 3, agreement: 1 },
  });
  expect(store.getSnapshot().live?.end?.success).toBe(true);
  expect(notified).toBe(7);
});

test("history rebuilds a joined episode; replay is shown beside it; errors are bounded", () => {
  const store = new Store();
  store.handle({ type: "history", episode_id: "h", start: fakeStart("h"), steps: [fakeStep("h", 0, [0, 0], [0])] });
  expect(store.getSnapshot().live?.steps.length).toBe(1);
  store.loadReplay({ start: fakeStart("r"), steps: [fakeStep("r", 0, [1, 1], [0])], end: null });
  expect(store.getSnapshot().replay?.id).toBe("r");
  expect(store.getSnapshot().live?.id).toBe("h");
  for (let i = 0; i < 9; i++) store.handle({ type: "error", message: `e${i}` });
  expect(store.getSnapshot().errors).toEqual(["e4", "e5", "e6", "e7", "e8"]);
  store.handle(fakeStart("next"));
  expect(store.getSnapshot().errors).toEqual([]); // a new episode clears the old one's errors
});

test("pause is the server's word: hello.running and status messages, cleared by the episode's end", () => {
  const store = new Store();
  const hello = (paused: boolean) => ({
    type: "hello" as const,
    version: "0",
    tasks: [],
    model_id: "m",
    probes: {
      layers: { object: 1, action: 1 },
      threshold: 0.5,
      atoms: { object: [], action: [] },
      probed: { object: [], action: [] },
    },
    image_hz: 5,
    num_init_states: 1,
    drivers: ["expert" as const],
    default_driver: "expert" as const,
    running: { episode_id: "p", paused },
  });
  store.handle(hello(true));
  expect(isPaused(store.getSnapshot())).toBe(false); // no episode shown yet
  store.handle({ type: "history", episode_id: "p", start: fakeStart("p"), steps: [fakeStep("p", 0, [0, 0], [0])] });
  expect(isPaused(store.getSnapshot())).toBe(true); // a late joiner learns it from hello
  store.handle({ type: "status", episode_id: "p", paused: false });
  expect(isPaused(store.getSnapshot())).toBe(false);
  store.handle({ type: "status", episode_id: "p", paused: true });
  expect(isPaused(store.getSnapshot())).toBe(true);
  store.handle({ type: "status", episode_id: "other", paused: true });
  expect(isPaused(store.getSnapshot())).toBe(false); // another episode's pause
  store.handle({ type: "status", episode_id: "p", paused: true });
  store.handle({
    type: "episode_end",
    episode_id: "p",
    success: false,
    steps: 1,
    stopped: true,
    summary: { violations: {}, goal_step_predicted: null, goal_step_truth: null, agreement: 1 },
  });
  expect(isPaused(store.getSnapshot())).toBe(false); // stopped while paused
});
