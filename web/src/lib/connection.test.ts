import { expect, test } from "vitest";
import { Connection, type SocketLike } from "./connection";

class FakeSocket implements SocketLike {
  onopen: ((ev: unknown) => void) | null = null;
  onclose: ((ev: unknown) => void) | null = null;
  onerror: ((ev: unknown) => void) | null = null;
  onmessage: ((ev: { data: unknown }) => void) | null = null;
  readyState = 0;
  sent: string[] = [];
  send(data: string): void {
    this.sent.push(data);
  }
  close(): void {
    this.readyState = 3;
    this.onclose?.({});
  }
  accept(): void {
    this.readyState = 1;
    this.onopen?.({});
  }
}

test("reconnects with growing delays and resets them after a successful open", () => {
  const sockets: FakeSocket[] = [];
  const states: [string, number | null][] = [];
  const messages: string[] = [];
  const pending: (() => void)[] = [];
  const conn = new Connection(
    () => {
      const s = new FakeSocket();
      sockets.push(s);
      return s;
    },
    { onMessage: (m) => messages.push(m), onState: (s, ms) => states.push([s, ms]) },
    { baseMs: 100, maxMs: 1000, factor: 2, jitter: 0 },
    { setTimeout: (fn) => pending.push(fn), clearTimeout: () => undefined },
  );
  conn.connect();
  expect(conn.send({ type: "stop" })).toBe(false);
  sockets[0]?.close();
  pending.shift()?.();
  sockets[1]?.close();
  pending.shift()?.();
  sockets[2]?.accept();
  sockets[2]?.onmessage?.({ data: '{"type":"hello"}' });
  expect(conn.send({ type: "stop" })).toBe(true);
  expect(sockets[2]?.sent).toEqual(['{"type":"stop"}']);
  sockets[2]?.close();
  expect(states).toEqual([
    ["connecting", null],
    ["reconnecting", 100],
    ["connecting", null],
    ["reconnecting", 200],
    ["connecting", null],
    ["open", null],
    ["reconnecting", 100],
  ]);
  expect(messages).toEqual(['{"type":"hello"}']);
  conn.dispose();
  expect(pending.length).toBe(1);
  pending.shift()?.();
  expect(sockets.length).toBe(3);
});
