/**
 * RTCM 3 frames (RTCM 10403.3): preamble 0xD3, 6 zero bits, 10-bit payload length, payload, CRC-24Q.
 * A DJI aircraft's raw GNSS log (*_PPKRAW.bin), an M4 .rtk file or a base receiver's log is a stream of
 * them with other records between. Walks the frames of a piece of a log (the head of a file) to say what
 * it holds: observation (MSM) messages and their systems, ephemerides, station position, epoch times of
 * week. Mirrors the server's frame scan (backend/services/file_kinds.py).
 */

const CRC24Q = (() => {
  const t = new Uint32Array(256);
  for (let i = 0; i < 256; i++) {
    let crc = i << 16;
    for (let k = 0; k < 8; k++) {
      crc <<= 1;
      if (crc & 0x1000000) crc ^= 0x1864cfb;
    }
    t[i] = crc & 0xffffff;
  }
  return t;
})();

export function crc24q(bytes: Uint8Array, start: number, end: number): number {
  let crc = 0;
  for (let i = start; i < end; i++) crc = ((crc << 8) & 0xffffff) ^ CRC24Q[((crc >>> 16) ^ bytes[i]) & 0xff];
  return crc;
}

/** Ephemeris message number -> system letter. */
export const EPHEMERIS_SYSTEM: Record<number, string> = { 1019: "G", 1020: "R", 1042: "C", 1044: "J", 1045: "E", 1046: "E" };
/** MSM message group (number / 10) -> system letter. */
export const MSM_SYSTEM: Record<number, string> = { 107: "G", 108: "R", 109: "E", 111: "J", 112: "C" };
export const SYSTEM_NAMES: Record<string, string> = { G: "GPS", R: "GLONASS", E: "Galileo", J: "QZSS", C: "BeiDou" };

export interface Rtcm3Summary {
  frames: number;
  bytesInFrames: number;
  messages: Record<number, number>;
  msm: number;
  systems: string[];
  ephemerides: number;
  /** Satellites with an ephemeris, per system letter. */
  ephemerisSatellites: Record<string, number>;
  station: boolean;
  /** GPS-time epoch of the first and last MSM (ms of the GPS week), null without MSM. */
  firstTowMs: number | null;
  lastTowMs: number | null;
}

/** Every CRC-valid frame of `bytes`, in stream order (frames cut by the end are left out). */
export function scanRtcm3(bytes: Uint8Array): Rtcm3Summary {
  const s: Rtcm3Summary = { frames: 0, bytesInFrames: 0, messages: {}, msm: 0, systems: [], ephemerides: 0, ephemerisSatellites: {}, station: false, firstTowMs: null, lastTowMs: null };
  const sats: Record<string, Set<number>> = {};
  const systems = new Set<string>();
  const n = bytes.length;
  let i = 0;
  while (i + 6 <= n) {
    if (bytes[i] !== 0xd3 || (bytes[i + 1] & 0xfc) !== 0) {
      i++;
      continue;
    }
    const len = ((bytes[i + 1] & 0x03) << 8) | bytes[i + 2];
    const end = i + 3 + len;
    if (len < 2 || end + 3 > n) {
      i++;
      continue;
    }
    const crc = (bytes[end] << 16) | (bytes[end + 1] << 8) | bytes[end + 2];
    if (crc24q(bytes, i, end) !== crc) {
      i++;
      continue;
    }
    const p = i + 3;
    const msg = (bytes[p] << 4) | (bytes[p + 1] >> 4);
    s.frames++;
    s.bytesInFrames += len + 6;
    s.messages[msg] = (s.messages[msg] ?? 0) + 1;
    const sys = EPHEMERIS_SYSTEM[msg];
    if (sys) {
      s.ephemerides++;
      const sat = msg === 1044 ? bytes[p + 1] & 0x0f : ((bytes[p + 1] & 0x0f) << 2) | (bytes[p + 2] >> 6);
      (sats[sys] ??= new Set()).add(sat);
    }
    const group = Math.floor(msg / 10);
    if (MSM_SYSTEM[group] && msg % 10 >= 1 && msg % 10 <= 7) {
      s.msm++;
      systems.add(MSM_SYSTEM[group]);
      if (group !== 108 && len >= 8) {
        const word = ((bytes[p + 3] << 24) >>> 0) + (bytes[p + 4] << 16) + (bytes[p + 5] << 8) + bytes[p + 6];
        const tow = Math.floor(word / 4) % 2 ** 30 + (group === 112 ? 14000 : 0);
        if (s.firstTowMs === null) s.firstTowMs = tow;
        s.lastTowMs = tow;
      }
    }
    if (msg === 1005 || msg === 1006) s.station = true;
    i = end + 3;
  }
  s.systems = [...systems].sort((a, b) => "GREJC".indexOf(a) - "GREJC".indexOf(b));
  for (const [k, v] of Object.entries(sats)) s.ephemerisSatellites[k] = v.size;
  return s;
}

/** Whether the bytes (the head of a file) are an RTCM 3 stream: at least two valid frames, covering more
 * of the bytes than UBX frames would (`ubxBytes`), as the server decides. */
export function looksLikeRtcm3(s: Rtcm3Summary, ubxBytes = 0): boolean {
  return s.frames >= 2 && s.bytesInFrames > ubxBytes;
}
