/**
 * u-blox UBX frames: sync 0xB5 0x62, class, id, little-endian length, payload, 8-bit Fletcher checksum.
 * Walks frames in a piece of a log (the head or the tail of a file) to find the receiver time span
 * (RXM-RAWX), whether the log carries navigation messages (RXM-SFRBX) and camera time marks (TIM-TM2).
 */

export const UBX_SYNC1 = 0xb5;
export const UBX_SYNC2 = 0x62;

export interface UbxSummary {
  frames: number;
  rawx: number;
  sfrbx: number;
  timTm2: number;
  firstMs: number | null;
  lastMs: number | null;
}

/** GPS week + time of week (s) as milliseconds of the GPS calendar (same scale as RINEX GPS times). */
export function gpsWeekTowToMs(week: number, towS: number): number {
  return Date.UTC(1980, 0, 6) + week * 604800000 + towS * 1000;
}

export function ubxChecksum(bytes: Uint8Array, start: number, end: number): [number, number] {
  let a = 0;
  let b = 0;
  for (let i = start; i < end; i++) {
    a = (a + bytes[i]) & 0xff;
    b = (b + a) & 0xff;
  }
  return [a, b];
}

export function emptyUbxSummary(): UbxSummary {
  return { frames: 0, rawx: 0, sfrbx: 0, timTm2: 0, firstMs: null, lastMs: null };
}

/** Frames found in `bytes` (which may start or end in the middle of a frame). */
export function scanUbx(bytes: Uint8Array): UbxSummary {
  const s = emptyUbxSummary();
  scanUbxInto(s, bytes);
  return s;
}

/**
 * Add the frames of `bytes` to `s`; returns the offset of the first byte not consumed (the start of a
 * frame cut by the end of the buffer), so that a streaming reader can prepend it to the next piece.
 */
export function scanUbxInto(s: UbxSummary, bytes: Uint8Array): number {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let i = 0;
  const n = bytes.length;
  while (i + 8 <= n) {
    if (bytes[i] !== UBX_SYNC1 || bytes[i + 1] !== UBX_SYNC2) {
      i++;
      continue;
    }
    const cls = bytes[i + 2];
    const id = bytes[i + 3];
    const len = dv.getUint16(i + 4, true);
    const end = i + 6 + len;
    if (end + 2 > n) return len > 8192 ? i + 1 : i;
    const [ca, cb] = ubxChecksum(bytes, i + 2, end);
    if (ca !== bytes[end] || cb !== bytes[end + 1]) {
      i++;
      continue;
    }
    s.frames++;
    if (cls === 0x02 && id === 0x15 && len >= 16) {
      const tow = dv.getFloat64(i + 6, true);
      const week = dv.getUint16(i + 6 + 8, true);
      const ms = gpsWeekTowToMs(week, tow);
      s.rawx++;
      if (s.firstMs === null) s.firstMs = ms;
      s.lastMs = ms;
    } else if (cls === 0x02 && id === 0x13) {
      s.sfrbx++;
    } else if (cls === 0x0d && id === 0x03) {
      s.timTm2++;
    }
    i = end + 2;
  }
  return i;
}

/** True when the bytes look like a UBX log: a valid frame in the first kilobytes. */
export function looksLikeUbx(bytes: Uint8Array): boolean {
  const head = bytes.subarray(0, 8192);
  return scanUbx(head).frames > 0;
}
