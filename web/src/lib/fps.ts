/** Frames per second measured over a sliding window of arrival times. */

export class FpsMeter {
  private readonly times: number[] = [];

  constructor(readonly windowMs: number = 2000) {}

  /** Records one frame that arrived at `now` (ms). */
  tick(now: number): void {
    this.times.push(now);
    this.prune(now);
  }

  /** Frames per second over the window ending at `now`; 0 with fewer than two frames. */
  fps(now: number): number {
    this.prune(now);
    const n = this.times.length;
    if (n < 2) return 0;
    const first = this.times[0] ?? now;
    const last = this.times[n - 1] ?? now;
    return last > first ? ((n - 1) * 1000) / (last - first) : 0;
  }

  private prune(now: number): void {
    while (this.times.length && (this.times[0] ?? now) < now - this.windowMs) this.times.shift();
  }
}
