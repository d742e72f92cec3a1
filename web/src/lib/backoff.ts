/** Reconnect delays: exponential from `baseMs` up to `maxMs`, with jitter so clients do not reconnect in step. */

export interface BackoffConfig {
  /** Delay before the first retry, in ms. */
  baseMs: number;
  /** Upper bound of any delay, in ms. */
  maxMs: number;
  /** Growth per failed attempt. */
  factor: number;
  /** Fraction of the delay drawn at random (0 = none, 0.2 = +-20 %). */
  jitter: number;
}

export const DEFAULT_BACKOFF: BackoffConfig = { baseMs: 250, maxMs: 5000, factor: 2, jitter: 0.2 };

/** Delay before retry number `attempt` (0-based); `random` in [0, 1). */
export function backoffDelay(attempt: number, config: BackoffConfig = DEFAULT_BACKOFF, random = Math.random()): number {
  const raw = Math.min(config.maxMs, config.baseMs * config.factor ** Math.max(0, attempt));
  const spread = raw * config.jitter * (2 * random - 1);
  return Math.round(Math.min(config.maxMs, Math.max(0, raw + spread)));
}
