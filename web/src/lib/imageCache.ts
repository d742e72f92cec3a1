/**
 * A bounded least-recently-used cache of camera frames (data URLs), so a long episode or many replays do
 * not grow the page's memory without limit. Bounded both by entry count and by total characters.
 */

export class ImageCache {
  private readonly entries = new Map<string, string>();
  private chars = 0;

  constructor(
    readonly maxEntries: number = 600,
    readonly maxChars: number = 24_000_000,
  ) {}

  get size(): number {
    return this.entries.size;
  }

  get totalChars(): number {
    return this.chars;
  }

  get(key: string): string | undefined {
    const value = this.entries.get(key);
    if (value !== undefined) {
      this.entries.delete(key);
      this.entries.set(key, value);
    }
    return value;
  }

  has(key: string): boolean {
    return this.entries.has(key);
  }

  set(key: string, value: string): void {
    const old = this.entries.get(key);
    if (old !== undefined) {
      this.entries.delete(key);
      this.chars -= old.length;
    }
    this.entries.set(key, value);
    this.chars += value.length;
    while (this.entries.size > this.maxEntries || (this.chars > this.maxChars && this.entries.size > 1)) {
      const oldest = this.entries.keys().next().value;
      if (oldest === undefined) break;
      this.chars -= this.entries.get(oldest)?.length ?? 0;
      this.entries.delete(oldest);
    }
  }

  clear(): void {
    this.entries.clear();
    this.chars = 0;
  }
}

export function frameKey(episodeId: string, t: number): string {
  return `${episodeId}/${t}`;
}
