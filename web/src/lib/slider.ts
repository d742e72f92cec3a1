/**
 * The timeline slider's state: the step shown, and whether it follows the newest step (live) or stays where
 * the user put it. Keys: arrows +-1, PageUp/PageDown +-10, Home/End.
 */

export interface SliderState {
  index: number;
  /** Follow the newest step as steps arrive. */
  follow: boolean;
}

export const PAGE = 10;

export function clampStep(index: number, count: number): number {
  if (count <= 0) return 0;
  return Math.min(count - 1, Math.max(0, Math.round(index)));
}

/** The slider after new steps arrived: at the end when following, else unchanged (but in range). */
export function onStepsChanged(state: SliderState, count: number): SliderState {
  const index = state.follow ? Math.max(0, count - 1) : clampStep(state.index, count);
  return index === state.index ? state : { ...state, index };
}

/** The user moved the slider to `index`; moving to the last step resumes following. */
export function seek(state: SliderState, index: number, count: number): SliderState {
  const i = clampStep(index, count);
  return { index: i, follow: i === count - 1 && state.follow };
}

/** The step after a key press, or null when the key is not a slider key. */
export function stepForKey(key: string, index: number, count: number): number | null {
  const moves: Record<string, number> = {
    ArrowLeft: index - 1,
    ArrowDown: index - 1,
    ArrowRight: index + 1,
    ArrowUp: index + 1,
    PageDown: index - PAGE,
    PageUp: index + PAGE,
    Home: 0,
    End: count - 1,
  };
  const target = moves[key];
  return target === undefined ? null : clampStep(target, count);
}
