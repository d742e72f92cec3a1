// Builds the UI into the Python package (src/vlaprobe/live/ui), which `vlaprobe serve` serves at /.
// `npm run dev` proxies the WebSocket and the REST API to a server on 127.0.0.1:6006.
import react from "@vitejs/plugin-react";
import { defineConfig } from "vitest/config";

export default defineConfig({
  plugins: [react()],
  base: "./",
  build: {
    outDir: "../src/vlaprobe/live/ui",
    emptyOutDir: true,
    chunkSizeWarningLimit: 1000,
  },
  server: {
    proxy: {
      "/api": "http://127.0.0.1:6006",
      "/ws": { target: "ws://127.0.0.1:6006", ws: true },
    },
  },
  test: {
    include: ["src/**/*.test.ts", "src/**/*.test.tsx", "test/**/*.test.ts"],
    environment: "node",
  },
});
