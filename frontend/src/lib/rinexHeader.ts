/**
 * RINEX header reading for the pre-flight check: version and type, marker, receiver, observation types,
 * TIME OF FIRST / LAST OBS, INTERVAL, and epoch lines (to find the last epoch and camera event records
 * when the header does not say). Times are kept in the file's own time system as milliseconds of a
 * proleptic calendar (Date.UTC), which is all an overlap check needs.
 */

export type RinexType = "obs" | "nav" | "met" | "other";

export interface RinexHeader {
  version: number;
  type: RinexType;
  /** Satellite system letter of the header (G, R, E, C, J, M = mixed...). */
  system: string;
  hatanaka: boolean;
  markerName: string;
  receiver: string;
  antenna: string;
  approxPositionEcefM: [number, number, number] | null;
  intervalS: number | null;
  firstObsMs: number | null;
  lastObsMs: number | null;
  timeSystem: string;
  /** Observation codes per system ("G" -> ["C1C", "L1C", ...]); RINEX 2 lists under "*". */
  obsTypes: Record<string, string[]>;
  /** Number of characters of the header including END OF HEADER, or -1 when it was not found. */
  headerLength: number;
}

const LABEL_START = 60;

function label(line: string): string {
  return line.length > LABEL_START ? line.slice(LABEL_START).trim() : "";
}

/** Calendar time of "yyyy mm dd hh mm ss.sssssss" fields (2-digit years: 80-99 -> 19xx, else 20xx). */
export function calendarMs(y: number, mo: number, d: number, h: number, mi: number, s: number): number {
  const year = y < 100 ? (y >= 80 ? 1900 + y : 2000 + y) : y;
  const whole = Math.floor(s);
  return Date.UTC(year, mo - 1, d, h, mi, whole) + Math.round((s - whole) * 1000);
}

/** Parse the "TIME OF FIRST OBS" / "TIME OF LAST OBS" value (columns 1-43, time system at 49-51). */
export function parseTimeOfObs(line: string): { ms: number; system: string } | null {
  const f = line.slice(0, 43).trim().split(/\s+/).map(Number);
  if (f.length < 6 || f.some((x) => !Number.isFinite(x))) return null;
  const [y, mo, d, h, mi, s] = f;
  if (mo < 1 || mo > 12 || d < 1 || d > 31 || h > 24 || mi > 59 || s >= 61) return null;
  return { ms: calendarMs(y, mo, d, h, mi, s), system: line.slice(48, 51).trim() };
}

function emptyHeader(): RinexHeader {
  return {
    version: 0, type: "other", system: "", hatanaka: false, markerName: "", receiver: "", antenna: "",
    approxPositionEcefM: null, intervalS: null, firstObsMs: null, lastObsMs: null, timeSystem: "",
    obsTypes: {}, headerLength: -1,
  };
}

/** True when the text starts like a RINEX (or Hatanaka-compressed RINEX) file. */
export function looksLikeRinex(text: string): boolean {
  const first = text.slice(0, text.indexOf("\n") >= 0 ? text.indexOf("\n") : 100);
  return first.includes("RINEX VERSION / TYPE") || first.includes("CRINEX VERS");
}

/**
 * Read a RINEX header from the first bytes of a (decompressed) file. Returns null when the text is not
 * RINEX. Works on a truncated head: fields after the cut are simply missing.
 */
export function parseRinexHeader(text: string): RinexHeader | null {
  const lines = text.split(/\r?\n/);
  const h = emptyHeader();
  let i = 0;
  if (lines[0]?.includes("CRINEX VERS")) {
    // Hatanaka: two CRINEX lines, then the ordinary RINEX header in clear text.
    h.hatanaka = true;
    i = 1;
    while (i < lines.length && !lines[i].includes("RINEX VERSION / TYPE")) {
      if (i > 3) return null;
      i++;
    }
  }
  const first = lines[i];
  if (!first || !first.includes("RINEX VERSION / TYPE")) return null;
  h.version = parseFloat(first.slice(0, 9));
  const t = first.charAt(20).toUpperCase();
  const up = first.slice(0, 60).toUpperCase();
  if (t === "O" || up.includes("OBSERVATION")) h.type = "obs";
  else if ("NGHLCEBJ".includes(t) && t !== " " && t !== "") h.type = "nav";
  else if (t === "M" && up.includes("MET")) h.type = "met";
  else if (up.includes("NAV")) h.type = "nav";
  h.system = first.charAt(40).trim() || (h.type === "nav" && t !== "N" ? t : "");
  let chars = 0;
  for (let k = 0; k < i; k++) chars += lines[k].length + 1;
  let lastSys = "";
  for (; i < lines.length; i++) {
    const line = lines[i];
    chars += line.length + 1;
    const lab = label(line);
    if (lab === "END OF HEADER") {
      h.headerLength = chars;
      break;
    }
    switch (lab) {
      case "MARKER NAME":
        h.markerName = line.slice(0, 60).trim();
        break;
      case "REC # / TYPE / VERS":
        h.receiver = line.slice(20, 40).trim();
        break;
      case "ANT # / TYPE":
        h.antenna = line.slice(20, 40).trim();
        break;
      case "APPROX POSITION XYZ": {
        const v = line.slice(0, 42).trim().split(/\s+/).map(Number);
        if (v.length === 3 && v.every(Number.isFinite)) h.approxPositionEcefM = [v[0], v[1], v[2]];
        break;
      }
      case "INTERVAL": {
        const v = parseFloat(line.slice(0, 10));
        if (Number.isFinite(v) && v > 0) h.intervalS = v;
        break;
      }
      case "TIME OF FIRST OBS": {
        const v = parseTimeOfObs(line);
        if (v) {
          h.firstObsMs = v.ms;
          h.timeSystem = v.system || (h.system === "R" ? "GLO" : "GPS");
        }
        break;
      }
      case "TIME OF LAST OBS": {
        const v = parseTimeOfObs(line);
        if (v) h.lastObsMs = v.ms;
        break;
      }
      case "SYS / # / OBS TYPES": {
        const sys = line.charAt(0).trim();
        const codes = line.slice(7, 60).trim().split(/\s+/).filter(Boolean);
        if (sys) {
          lastSys = sys;
          h.obsTypes[sys] = codes;
        } else if (lastSys) {
          h.obsTypes[lastSys].push(...codes);
        }
        break;
      }
      case "# / TYPES OF OBSERV": {
        const codes = line.slice(6, 60).trim().split(/\s+/).filter(Boolean);
        h.obsTypes["*"] = [...(h.obsTypes["*"] ?? []), ...codes];
        break;
      }
    }
  }
  return h;
}

/** Frequencies observed with carrier phase: "L1", "L1+L2", ... (from the observation types). */
export function phaseBands(h: RinexHeader): string[] {
  const bands = new Set<string>();
  for (const codes of Object.values(h.obsTypes)) {
    for (const c of codes) if (c.startsWith("L") && c.length >= 2) bands.add(`L${c.charAt(1)}`);
  }
  return [...bands].sort();
}

export interface EpochLine {
  ms: number;
  flag: number;
}

const RE_EPOCH3 = /^>\s*(\d{4})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d+\.\d*)\s+(\d)/;
const RE_EPOCH2 = /^\s?(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d+\.\d+)\s+(\d)/;

/** Parse one observation epoch line of RINEX 3 ("> yyyy ...") or RINEX 2 (" yy mm dd ..."), else null. */
export function parseEpochLine(line: string, version: number): EpochLine | null {
  const m = (version >= 3 ? RE_EPOCH3 : RE_EPOCH2).exec(line);
  if (!m) return null;
  const v = m.slice(1, 8).map(Number);
  if (v[1] < 1 || v[1] > 12 || v[2] < 1 || v[2] > 31) return null;
  return { ms: calendarMs(v[0], v[1], v[2], v[3], v[4], v[5]), flag: v[6] };
}

/** The last epoch time found in a piece of text (the tail of an observation file), or null. */
export function lastEpochIn(text: string, version: number): number | null {
  const lines = text.split(/\r?\n/);
  for (let i = lines.length - 1; i >= 0; i--) {
    const e = parseEpochLine(lines[i], version);
    if (e && e.flag <= 1) return e.ms;
  }
  return null;
}

/**
 * Streaming scan of the observation records: counts epochs and camera event records (epoch flag 5),
 * and keeps the first and last epoch times. Feed text pieces in order with push(), read result().
 */
export class EpochScanner {
  private rest = "";
  private inHeader: boolean;
  epochs = 0;
  events = 0;
  firstMs: number | null = null;
  lastMs: number | null = null;

  constructor(private version: number, startsWithHeader = true) {
    this.inHeader = startsWithHeader;
  }

  push(text: string): void {
    const all = this.rest + text;
    const lines = all.split("\n");
    this.rest = lines.pop() ?? "";
    for (const raw of lines) this.line(raw);
  }

  finish(): void {
    if (this.rest) this.line(this.rest);
    this.rest = "";
  }

  private line(raw: string): void {
    if (this.inHeader) {
      if (raw.includes("END OF HEADER")) this.inHeader = false;
      return;
    }
    const c = this.version >= 3 ? raw.charCodeAt(0) === 62 /* > */ : raw.length > 28 && raw.charAt(3) === " ";
    if (!c) return;
    const e = parseEpochLine(raw, this.version);
    if (!e) return;
    if (e.flag === 5) this.events++;
    else if (e.flag <= 1) {
      this.epochs++;
      if (this.firstMs === null) this.firstMs = e.ms;
      this.lastMs = e.ms;
    }
  }
}

/** First record time of a RINEX navigation file body (the text after END OF HEADER), or null. */
export function firstNavRecordMs(text: string, version: number): number | null {
  const end = text.indexOf("END OF HEADER");
  if (end < 0) return null;
  const body = text.slice(text.indexOf("\n", end) + 1).split(/\r?\n/);
  for (const line of body.slice(0, 40)) {
    if (version >= 3) {
      const m = /^[A-Z][ \d]\d\s(\d{4})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})/.exec(line);
      if (m) return calendarMs(+m[1], +m[2], +m[3], +m[4], +m[5], +m[6]);
    } else {
      const m = /^[ \d]\d\s+(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d{1,2})\s+(\d+\.\d)/.exec(line);
      if (m) return calendarMs(+m[1], +m[2], +m[3], +m[4], +m[5], +m[6]);
    }
  }
  return null;
}
