/**
 * Incremental SHA-256 (FIPS 180-4). WebCrypto's digest() needs the whole message in memory at once,
 * which is not possible for multi-gigabyte image archives; this one takes the file chunk by chunk.
 */

const K = new Uint32Array([
  0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
  0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
  0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
  0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
  0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
  0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
  0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
  0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2,
]);

export class Sha256 {
  private h = new Uint32Array([
    0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19,
  ]);
  private w = new Uint32Array(64);
  private buf = new Uint8Array(64);
  private bufLen = 0;
  private bytes = 0; // total message length so far (a double is exact up to 2^53 bytes)
  private done = false;

  update(data: Uint8Array): this {
    if (this.done) throw new Error("Sha256: update() after digest()");
    let off = 0;
    const n = data.length;
    this.bytes += n;
    if (this.bufLen > 0) {
      const take = Math.min(64 - this.bufLen, n);
      this.buf.set(data.subarray(0, take), this.bufLen);
      this.bufLen += take;
      off = take;
      if (this.bufLen === 64) {
        this.blocks(this.buf, 0, 64);
        this.bufLen = 0;
      }
    }
    const full = off + Math.floor((n - off) / 64) * 64;
    if (full > off) {
      this.blocks(data, off, full);
      off = full;
    }
    if (off < n) {
      this.buf.set(data.subarray(off), 0);
      this.bufLen = n - off;
    }
    return this;
  }

  /** The digest as 32 bytes; the hasher cannot be updated afterwards. */
  digest(): Uint8Array {
    if (!this.done) {
      const bitsHi = Math.floor(this.bytes / 0x20000000);
      const bitsLo = (this.bytes * 8) >>> 0;
      const padLen = this.bufLen < 56 ? 64 : 128;
      const pad = new Uint8Array(padLen);
      pad.set(this.buf.subarray(0, this.bufLen));
      pad[this.bufLen] = 0x80;
      const dv = new DataView(pad.buffer);
      dv.setUint32(padLen - 8, bitsHi);
      dv.setUint32(padLen - 4, bitsLo);
      this.blocks(pad, 0, padLen);
      this.done = true;
    }
    const out = new Uint8Array(32);
    const dv = new DataView(out.buffer);
    for (let i = 0; i < 8; i++) dv.setUint32(i * 4, this.h[i]);
    return out;
  }

  hex(): string {
    return toHex(this.digest());
  }

  private blocks(p: Uint8Array, start: number, end: number): void {
    const w = this.w;
    const h = this.h;
    let h0 = h[0], h1 = h[1], h2 = h[2], h3 = h[3], h4 = h[4], h5 = h[5], h6 = h[6], h7 = h[7];
    for (let pos = start; pos < end; pos += 64) {
      for (let i = 0; i < 16; i++) {
        const j = pos + i * 4;
        w[i] = (p[j] << 24) | (p[j + 1] << 16) | (p[j + 2] << 8) | p[j + 3];
      }
      for (let i = 16; i < 64; i++) {
        const a = w[i - 15], b = w[i - 2];
        const s0 = ((a >>> 7) | (a << 25)) ^ ((a >>> 18) | (a << 14)) ^ (a >>> 3);
        const s1 = ((b >>> 17) | (b << 15)) ^ ((b >>> 19) | (b << 13)) ^ (b >>> 10);
        w[i] = (w[i - 16] + s0 + w[i - 7] + s1) | 0;
      }
      let a = h0, b = h1, c = h2, d = h3, e = h4, f = h5, g = h6, hh = h7;
      for (let i = 0; i < 64; i++) {
        const S1 = ((e >>> 6) | (e << 26)) ^ ((e >>> 11) | (e << 21)) ^ ((e >>> 25) | (e << 7));
        const ch = (e & f) ^ (~e & g);
        const t1 = (hh + S1 + ch + K[i] + w[i]) | 0;
        const S0 = ((a >>> 2) | (a << 30)) ^ ((a >>> 13) | (a << 19)) ^ ((a >>> 22) | (a << 10));
        const maj = (a & b) ^ (a & c) ^ (b & c);
        const t2 = (S0 + maj) | 0;
        hh = g; g = f; f = e; e = (d + t1) | 0;
        d = c; c = b; b = a; a = (t1 + t2) | 0;
      }
      h0 = (h0 + a) | 0; h1 = (h1 + b) | 0; h2 = (h2 + c) | 0; h3 = (h3 + d) | 0;
      h4 = (h4 + e) | 0; h5 = (h5 + f) | 0; h6 = (h6 + g) | 0; h7 = (h7 + hh) | 0;
    }
    h[0] = h0; h[1] = h1; h[2] = h2; h[3] = h3; h[4] = h4; h[5] = h5; h[6] = h6; h[7] = h7;
  }
}

export function toHex(bytes: Uint8Array): string {
  let s = "";
  for (let i = 0; i < bytes.length; i++) s += bytes[i].toString(16).padStart(2, "0");
  return s;
}

/** Something File-like: size and slice() returning a Blob (a File, a Blob, or a test double). */
export interface Sliceable {
  size: number;
  slice(start: number, end: number): Blob;
}

export const HASH_READ_BYTES = 4 * 1024 * 1024;

/** SHA-256 hex of a File/Blob, read in slices so that memory stays bounded; onProgress(bytesDone). */
export async function sha256OfBlob(
  blob: Sliceable,
  onProgress?: (done: number) => void,
  signal?: AbortSignal,
  readBytes = HASH_READ_BYTES,
): Promise<string> {
  const hasher = new Sha256();
  for (let off = 0; off < blob.size; off += readBytes) {
    if (signal?.aborted) throw new DOMException("hashing aborted", "AbortError");
    const part = new Uint8Array(await blob.slice(off, Math.min(blob.size, off + readBytes)).arrayBuffer());
    hasher.update(part);
    onProgress?.(Math.min(blob.size, off + readBytes));
  }
  return hasher.hex();
}

/** Files up to this size are hashed by WebCrypto in one call (native speed); larger ones incrementally. */
export const WEBCRYPTO_MAX_BYTES = 256 * 1024 * 1024;

/**
 * SHA-256 hex of a File/Blob: WebCrypto's native digest for files that fit comfortably in memory (a
 * drone photo), the incremental implementation above for larger ones or where WebCrypto is missing
 * (pages served over plain http from another host are not a secure context).
 */
export async function sha256Fast(blob: Blob, onProgress?: (done: number) => void, signal?: AbortSignal): Promise<string> {
  const subtle = (globalThis.crypto as Crypto | undefined)?.subtle;
  if (subtle && blob.size <= WEBCRYPTO_MAX_BYTES) {
    const digest = await subtle.digest("SHA-256", await blob.arrayBuffer());
    onProgress?.(blob.size);
    return toHex(new Uint8Array(digest));
  }
  return sha256OfBlob(blob, onProgress, signal);
}
