/** Resumable uploads: which byte ranges to send, and their Content-Range headers. */

export const DEFAULT_CHUNK_BYTES = 8 * 1024 * 1024;

export interface ChunkRange {
  start: number;
  /** Exclusive end. */
  end: number;
}

/** The chunks still to send for a file of `size` bytes when the server already has `received`. */
export function planChunks(size: number, received: number, chunkBytes = DEFAULT_CHUNK_BYTES): ChunkRange[] {
  if (!(chunkBytes > 0)) throw new Error("chunk size must be positive");
  if (received < 0 || received > size) throw new Error(`received bytes ${received} outside 0..${size}`);
  const out: ChunkRange[] = [];
  for (let s = received; s < size; s += chunkBytes) out.push({ start: s, end: Math.min(size, s + chunkBytes) });
  return out;
}

/** `bytes START-END/SIZE` with END inclusive (RFC 9110 §14.4). */
export function contentRange(c: ChunkRange, size: number): string {
  if (c.end <= c.start) throw new Error("empty chunk");
  return `bytes ${c.start}-${c.end - 1}/${size}`;
}

/** Retry delays (ms) with exponential backoff and a cap: 1 s, 2 s, 4 s ... 30 s. */
export function backoffMs(attempt: number, baseMs = 1000, capMs = 30000): number {
  return Math.min(capMs, baseMs * 2 ** Math.max(0, attempt));
}

/** A stable key of a local file for resuming after a page reload (same name, size and date = same file). */
export function fileKey(surveyId: string, path: string, size: number, lastModified: number): string {
  return `georef.upload:${surveyId}:${path}:${size}:${lastModified}`;
}
