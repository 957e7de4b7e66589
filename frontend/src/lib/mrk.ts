/**
 * DJI *_Timestamp.MRK: one text line per camera exposure,
 * `index  seconds-of-week  [week]  n,N  e,E  v,V  lat,Lat  lon,Lon  h,Ellh  sn, se, sv  q,Q`.
 * Recognised by its first line (as the server and the pipeline do), summarised for the pre-check.
 */

const NUM = String.raw`[-+]?(?:\d+\.?\d*|\.\d+)`;
const MRK_LINE = new RegExp(String.raw`^\s*\d+\s+\d+(?:\.\d*)?\s+\[\s*\d+\s*\]\s+${NUM}\s*,\s*N\s+${NUM}\s*,\s*E\s+${NUM}\s*,\s*V\b`);
const MRK_TIME = /^\s*(\d+)\s+(\d+(?:\.\d*)?)\s+\[\s*(\d+)\s*\]/;

export interface MrkSummary {
  exposures: number;
  firstIndex: number | null;
  lastIndex: number | null;
  /** GPS time of the first and last exposure, ms of the GPS calendar (same scale as RINEX GPS times). */
  firstMs: number | null;
  lastMs: number | null;
  /** Lines that do not read as exposures (1-based line numbers, the first few). */
  badLines: number[];
}

export function looksLikeMrk(text: string): boolean {
  const first = text.replace(/^\ufeff/, "").split("\n").find((l) => l.trim());
  return !!first && MRK_LINE.test(first);
}

const GPS_EPOCH_MS = Date.UTC(1980, 0, 6);

/** Exposures of an MRK text (a last line cut off while the file was written is not counted). */
export function parseMrk(text: string): MrkSummary {
  const s: MrkSummary = { exposures: 0, firstIndex: null, lastIndex: null, firstMs: null, lastMs: null, badLines: [] };
  const lines = text.replace(/^\ufeff/, "").split("\n");
  const complete = text.endsWith("\n");
  lines.forEach((line, k) => {
    if (!line.trim()) return;
    const m = MRK_TIME.exec(line);
    if (!m || !MRK_LINE.test(line)) {
      if (!(k === lines.length - 1 && !complete) && s.badLines.length < 5) s.badLines.push(k + 1);
      return;
    }
    const ms = GPS_EPOCH_MS + (Number(m[3]) * 604800 + Number(m[2])) * 1000;
    s.exposures++;
    if (s.firstIndex === null) {
      s.firstIndex = Number(m[1]);
      s.firstMs = ms;
    }
    s.lastIndex = Number(m[1]);
    s.lastMs = ms;
  });
  return s;
}
