// src/protocol.ts must be what json-schema-to-typescript makes of the server's schema today.
import { readFileSync } from "node:fs";
import { expect, test } from "vitest";
// @ts-expect-error: plain ES module without type declarations
import { generate, outPath } from "../scripts/gen-types.mjs";

test("src/protocol.ts is generated from the current schema (run `npm run gen:types` when this fails)", async () => {
  const expected: string = await generate();
  expect(readFileSync(outPath as string, "utf8")).toBe(expected);
}, 30_000);
