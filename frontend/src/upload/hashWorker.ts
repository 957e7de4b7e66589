/// <reference lib="webworker" />
/** Hashes files off the main thread so that the page stays responsive on large surveys. */
import { sha256Fast } from "../lib/sha256";

interface HashRequest {
  id: number;
  file: Blob;
}

self.onmessage = async (e: MessageEvent<HashRequest>) => {
  const { id, file } = e.data;
  try {
    let last = 0;
    const hex = await sha256Fast(file, (done) => {
      const now = performance.now();
      if (now - last > 100 || done === file.size) {
        last = now;
        (self as unknown as Worker).postMessage({ id, progress: done });
      }
    });
    (self as unknown as Worker).postMessage({ id, hex });
  } catch (err) {
    (self as unknown as Worker).postMessage({ id, error: String((err as Error)?.message ?? err) });
  }
};
