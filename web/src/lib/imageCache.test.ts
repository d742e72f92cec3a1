import { expect, test } from "vitest";
import { ImageCache, frameKey } from "./imageCache";

test("evicts the least recently used entry beyond the entry limit", () => {
  const c = new ImageCache(3, 1_000);
  for (const k of ["a", "b", "c"]) c.set(k, k.repeat(10));
  expect(c.get("a")).toBe("aaaaaaaaaa");
  c.set("d", "d");
  expect(c.has("b")).toBe(false);
  expect(c.has("a")).toBe(true);
  expect(c.size).toBe(3);
  expect(c.totalChars).toBe(21);
});

test("evicts beyond the size limit, and 10 Hz x 300 steps stays bounded", () => {
  const c = new ImageCache(100, 50);
  c.set("a", "x".repeat(30));
  c.set("b", "y".repeat(30));
  expect(c.has("a")).toBe(false);
  expect(c.totalChars).toBe(30);
  const big = new ImageCache(120, 10_000_000);
  for (let t = 0; t < 3000; t++) big.set(frameKey("e", t), "z".repeat(20_000));
  expect(big.size).toBe(120);
  expect(big.has(frameKey("e", 2999))).toBe(true);
  c.set("b", "short");
  expect(c.totalChars).toBe(5);
});
