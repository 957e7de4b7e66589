/** A small pool of hashing workers (falls back to the main thread where workers are unavailable). */
import { sha256Fast } from "../lib/sha256";

type Pending = { resolve: (hex: string) => void; reject: (e: Error) => void; onProgress?: (n: number) => void };

class HashPool {
  private workers: Worker[] = [];
  private busy = new Map<Worker, number>();
  private queue: { id: number; file: Blob }[] = [];
  private pending = new Map<number, Pending>();
  private nextId = 1;

  constructor(size: number) {
    if (typeof Worker === "undefined") return;
    for (let i = 0; i < size; i++) {
      try {
        const w = new Worker(new URL("./hashWorker.ts", import.meta.url), { type: "module" });
        w.onmessage = (e) => this.onMessage(w, e.data);
        w.onerror = (e) => {
          const id = this.busy.get(w);
          if (id !== undefined) this.finish(w, id, undefined, new Error(e.message || "hashing worker failed"));
        };
        this.workers.push(w);
      } catch {
        break;
      }
    }
  }

  hash(file: Blob, onProgress?: (n: number) => void): Promise<string> {
    if (!this.workers.length) return sha256Fast(file, onProgress);
    return new Promise((resolve, reject) => {
      const id = this.nextId++;
      this.pending.set(id, { resolve, reject, onProgress });
      this.queue.push({ id, file });
      this.pump();
    });
  }

  private pump() {
    for (const w of this.workers) {
      if (this.busy.has(w) || !this.queue.length) continue;
      const job = this.queue.shift()!;
      this.busy.set(w, job.id);
      w.postMessage(job);
    }
  }

  private onMessage(w: Worker, m: { id: number; progress?: number; hex?: string; error?: string }) {
    const p = this.pending.get(m.id);
    if (!p) return;
    if (m.progress !== undefined) p.onProgress?.(m.progress);
    if (m.hex !== undefined) this.finish(w, m.id, m.hex);
    if (m.error !== undefined) this.finish(w, m.id, undefined, new Error(m.error));
  }

  private finish(w: Worker, id: number, hex?: string, err?: Error) {
    const p = this.pending.get(id);
    this.pending.delete(id);
    this.busy.delete(w);
    if (p) {
      if (err) p.reject(err);
      else p.resolve(hex!);
    }
    this.pump();
  }
}

let pool: HashPool | null = null;

export function hashFile(file: Blob, onProgress?: (n: number) => void): Promise<string> {
  if (!pool) pool = new HashPool(Math.max(1, Math.min(3, (navigator.hardwareConcurrency || 2) - 1)));
  return pool.hash(file, onProgress);
}
