/// <reference types="vitest/config" />
import { defineConfig } from "vite";

// The backend serves dist/ at / (same origin: the session cookie and CSRF header just work).
// `npm run dev` proxies /api to a backend on GEOREF_API (default http://127.0.0.1:8000).
const api = process.env.GEOREF_API ?? "http://127.0.0.1:8000";

export default defineConfig({
  esbuild: { jsx: "automatic", jsxImportSource: "preact" },
  build: {
    target: "es2022",
    sourcemap: false,
    chunkSizeWarningLimit: 800,
  },
  worker: { format: "es" },
  server: { proxy: { "/api": { target: api, changeOrigin: false } } },
  test: {
    include: ["tests/**/*.test.ts"],
    environment: "node",
  },
});
