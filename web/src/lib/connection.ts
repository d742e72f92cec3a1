/**
 * The WebSocket to the server, reconnected automatically with backoff. The socket factory is injectable
 * so the reconnect logic is tested without a network.
 */
import { type BackoffConfig, DEFAULT_BACKOFF, backoffDelay } from "./backoff";

export type ConnectionState = "connecting" | "open" | "reconnecting";

export interface SocketLike {
  onopen: ((ev: unknown) => void) | null;
  onclose: ((ev: unknown) => void) | null;
  onerror: ((ev: unknown) => void) | null;
  onmessage: ((ev: { data: unknown }) => void) | null;
  send(data: string): void;
  close(): void;
  readonly readyState: number;
}

export interface ConnectionEvents {
  onMessage(text: string): void;
  onState(state: ConnectionState, retryInMs: number | null): void;
}

export interface Timers {
  setTimeout(fn: () => void, ms: number): unknown;
  clearTimeout(handle: unknown): void;
}

const OPEN = 1;

export class Connection {
  private socket: SocketLike | null = null;
  private attempt = 0;
  private timer: unknown = null;
  private closed = false;

  constructor(
    private readonly open: () => SocketLike,
    private readonly events: ConnectionEvents,
    private readonly backoff: BackoffConfig = DEFAULT_BACKOFF,
    private readonly timers: Timers = {
      setTimeout: (fn, ms) => globalThis.setTimeout(fn, ms),
      clearTimeout: (h) => globalThis.clearTimeout(h as ReturnType<typeof setTimeout>),
    },
  ) {}

  connect(): void {
    this.closed = false;
    this.events.onState("connecting", null);
    const socket = this.open();
    this.socket = socket;
    socket.onopen = () => {
      this.attempt = 0;
      this.events.onState("open", null);
    };
    socket.onmessage = (ev) => {
      if (typeof ev.data === "string") this.events.onMessage(ev.data);
    };
    socket.onerror = () => socket.close();
    socket.onclose = () => {
      if (this.socket !== socket || this.closed) return;
      this.socket = null;
      const delay = backoffDelay(this.attempt++, this.backoff);
      this.events.onState("reconnecting", delay);
      this.timer = this.timers.setTimeout(() => {
        this.timer = null;
        if (!this.closed) this.connect();
      }, delay);
    };
  }

  /** Sends a message; false when the socket is not open (the caller shows that). */
  send(message: object): boolean {
    if (!this.socket || this.socket.readyState !== OPEN) return false;
    this.socket.send(JSON.stringify(message));
    return true;
  }

  /** Closes for good (no reconnect). */
  dispose(): void {
    this.closed = true;
    if (this.timer !== null) this.timers.clearTimeout(this.timer);
    this.socket?.close();
    this.socket = null;
  }
}
