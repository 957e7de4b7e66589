/**
 * Resumable uploads of a survey's files: SHA-256 first (the server verifies it), then chunks with
 * Content-Range from the server's received_bytes, retries with backoff, and `complete`. The upload id
 * and hash of each local file are remembered (localStorage), so that dropping the same files again
 * after a reload or a lost connection resumes where the server stopped.
 */

import { ApiError, api, apiUrl, csrfHeader } from "../api/client";
import type { Upload } from "../api/types";
import { DEFAULT_CHUNK_BYTES, backoffMs, contentRange, fileKey, planChunks } from "../lib/chunks";
import type { ObsRole, UploadKind } from "../lib/sniff";
import { hashFile } from "./hashPool";

export type ItemState = "waiting" | "hashing" | "uploading" | "verifying" | "done" | "error" | "paused";

export interface UploadItem {
  key: string;
  file: File;
  path: string;
  kind: UploadKind;
  role: ObsRole | null;
  /** The folder a DJI flight's file was in (sent with kind=flight). */
  folder?: string;
  size: number;
  state: ItemState;
  hashed: number;
  sent: number;
  sha256?: string;
  uploadId?: string;
  error?: string;
  attached?: string;
  attempts: number;
}

interface Remembered {
  uploadId?: string;
  sha256?: string;
}

const MAX_ATTEMPTS = 6;

function remember(key: string, v: Remembered | null) {
  try {
    if (v) localStorage.setItem(key, JSON.stringify(v));
    else localStorage.removeItem(key);
  } catch {
    /* storage full or disabled: resuming works within this page only */
  }
}

function recall(key: string): Remembered {
  try {
    return JSON.parse(localStorage.getItem(key) ?? "{}");
  } catch {
    return {};
  }
}

const sleep = (ms: number, signal: AbortSignal) =>
  new Promise<void>((resolve, reject) => {
    const t = setTimeout(resolve, ms);
    signal.addEventListener("abort", () => {
      clearTimeout(t);
      reject(new DOMException("paused", "AbortError"));
    }, { once: true });
  });

export class UploadQueue {
  items: UploadItem[] = [];
  running = false;
  private ac: AbortController | null = null;
  private startedAt = 0;
  private sentAtStart = 0;

  constructor(
    private surveyId: string,
    private onChange: () => void,
    private concurrency = 3,
    private chunkBytes = DEFAULT_CHUNK_BYTES,
  ) {}

  add(files: { file: File; path: string; kind: UploadKind; role: ObsRole | null; folder?: string }[]): void {
    for (const f of files) {
      const key = fileKey(this.surveyId, f.path, f.file.size, f.file.lastModified);
      if (this.items.some((i) => i.key === key)) continue;
      this.items.push({ key, file: f.file, path: f.path, kind: f.kind, role: f.role, folder: f.folder, size: f.file.size, state: "waiting", hashed: 0, sent: 0, attempts: 0 });
    }
    this.onChange();
  }

  get totalBytes(): number {
    return this.items.reduce((a, i) => a + i.size, 0);
  }

  get sentBytes(): number {
    return this.items.reduce((a, i) => a + (i.state === "done" ? i.size : i.sent), 0);
  }

  get hashedBytes(): number {
    return this.items.reduce((a, i) => a + (i.sha256 ? i.size : i.hashed), 0);
  }

  /** Bytes per second since start() (null before any progress). */
  get rate(): number | null {
    const dt = (performance.now() - this.startedAt) / 1000;
    const db = this.sentBytes - this.sentAtStart;
    return this.running && dt > 1 && db > 0 ? db / dt : null;
  }

  get finished(): boolean {
    return this.items.length > 0 && this.items.every((i) => i.state === "done");
  }

  start(): void {
    if (this.running) return;
    this.running = true;
    this.ac = new AbortController();
    this.startedAt = performance.now();
    this.sentAtStart = this.sentBytes;
    for (const i of this.items) if (i.state === "paused" || i.state === "error") {
      i.state = "waiting";
      i.attempts = 0;
      i.error = undefined;
    }
    this.onChange();
    const signal = this.ac.signal;
    const worker = async () => {
      for (;;) {
        if (signal.aborted) return;
        const next = this.items.find((i) => i.state === "waiting");
        if (!next) return;
        next.state = "hashing";
        await this.process(next, signal);
      }
    };
    Promise.all(Array.from({ length: this.concurrency }, worker)).finally(() => {
      this.running = false;
      this.onChange();
    });
  }

  pause(): void {
    this.ac?.abort();
    for (const i of this.items) if (i.state !== "done" && i.state !== "error") i.state = "paused";
    this.onChange();
  }

  private async process(item: UploadItem, signal: AbortSignal): Promise<void> {
    try {
      const mem = recall(item.key);
      if (!item.sha256) {
        if (mem.sha256) item.sha256 = mem.sha256;
        else {
          item.state = "hashing";
          this.onChange();
          let last = 0;
          item.sha256 = await hashFile(item.file, (n) => {
            item.hashed = n;
            const now = performance.now();
            if (now - last > 150) {
              last = now;
              this.onChange();
            }
          });
          remember(item.key, { sha256: item.sha256 });
        }
      }
      if (signal.aborted) throw new DOMException("paused", "AbortError");
      let up: Upload | null = null;
      const known = item.uploadId ?? mem.uploadId;
      if (known) {
        try {
          up = await api.get<Upload>(`/uploads/${known}`, { signal });
          if (up.sha256 !== item.sha256 || up.size !== item.size || up.state === "failed" || up.state === "aborted") up = null;
        } catch (e) {
          if (!(e instanceof ApiError) || e.status !== 404) throw e;
          up = null;
        }
      }
      if (!up) {
        up = await api.post<Upload>(`/surveys/${this.surveyId}/uploads`, {
          filename: item.path.split("/").pop(), size: item.size, sha256: item.sha256, kind: item.kind, role: item.role ?? undefined,
          folder: item.folder,
        }, { signal });
      }
      item.uploadId = up.id;
      remember(item.key, { uploadId: up.id, sha256: item.sha256 });
      if (up.state !== "complete") {
        item.state = "uploading";
        item.sent = up.received_bytes;
        this.onChange();
        const chunk = Math.min(this.chunkBytes, up.max_chunk_bytes || this.chunkBytes);
        await this.sendChunks(item, up.received_bytes, chunk, signal);
        item.state = "verifying";
        this.onChange();
        up = await api.post<Upload>(`/uploads/${up.id}/complete`, {}, { signal });
      }
      item.state = "done";
      item.sent = item.size;
      item.attached = describeResult(up);
      remember(item.key, null);
      this.onChange();
    } catch (e) {
      if ((e as Error).name === "AbortError") {
        item.state = "paused";
      } else if (e instanceof ApiError && e.status >= 400 && e.status < 500 && e.status !== 408 && e.status !== 429) {
        item.state = "error";
        item.error = e.message;
        if (e.status === 422) remember(item.key, null); // refused content: a retry starts afresh
      } else if (item.attempts < MAX_ATTEMPTS) {
        item.attempts++;
        item.error = `${(e as Error).message} — retrying`;
        this.onChange();
        try {
          await sleep(backoffMs(item.attempts - 1), signal);
          item.state = "waiting";
        } catch {
          item.state = "paused";
        }
      } else {
        item.state = "error";
        item.error = (e as Error).message;
      }
      this.onChange();
    }
  }

  private async sendChunks(item: UploadItem, from: number, chunkBytes: number, signal: AbortSignal): Promise<void> {
    let offset = from;
    while (offset < item.size) {
      const [c] = planChunks(item.size, offset, chunkBytes);
      const res = await fetch(apiUrl(`/uploads/${item.uploadId}`), {
        method: "PUT",
        credentials: "same-origin",
        headers: { "Content-Type": "application/octet-stream", "Content-Range": contentRange(c, item.size), ...csrfHeader() },
        body: item.file.slice(c.start, c.end),
        signal,
      });
      if (res.ok) {
        const up = (await res.json()) as Upload;
        offset = up.received_bytes;
      } else {
        let problem: any = null;
        try {
          problem = await res.json();
        } catch {
          /* not JSON */
        }
        if ((res.status === 409 || res.status === 416) && typeof problem?.received_bytes === "number") {
          offset = problem.received_bytes; // the server has a different offset: continue from there
          continue;
        }
        throw new ApiError(res.status, problem?.detail ?? `${res.status} ${res.statusText}`, problem);
      }
      item.sent = offset;
      item.attempts = 0;
      item.error = undefined;
      this.onChange();
    }
  }
}

function describeResult(up: Upload): string {
  const r = up.result as any;
  if (!r) return "";
  const files = r.files ?? r.attached ?? r.placed;
  if (Array.isArray(files)) {
    const paths = files.map((f: any) => (typeof f === "string" ? f : f.path)).filter(Boolean);
    if (paths.length === 1) return paths[0];
    if (paths.length) return `${paths.length} files`;
  }
  return typeof r.path === "string" ? r.path : "";
}
