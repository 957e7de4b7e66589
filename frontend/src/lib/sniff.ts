/**
 * Recognise survey files by their content (the first bytes), not their names: RINEX observation and
 * navigation files (plain, Hatanaka CRINEX, gzip, Unix compress), u-blox UBX logs, RTCM 3 logs (a DJI
 * aircraft's *_PPKRAW.bin, base receiver logs), DJI *_Timestamp.MRK exposure files, JPEG/TIFF photos,
 * ground-point tables, ODM gcp_list.txt, camera-event tables and zip archives. The folder a file was
 * dropped in only breaks ties (rover vs base observation files) and ties a DJI flight's files together.
 */

import { type Compression, inflateHead } from "./decompress";
import { type ExifTime, exifCaptureTime } from "./exif";
import { type RinexHeader, firstNavRecordMs, parseRinexHeader, phaseBands } from "./rinexHeader";
import {
  type EventsTable, type GcpListTable, type PointsTable,
  looksLikeEventsCsv, looksLikeGcpList, looksLikePointsCsv, parseEventsCsv, parseGcpList, parsePointsCsv,
} from "./tables";
import { type MrkSummary, looksLikeMrk, parseMrk } from "./mrk";
import { type Rtcm3Summary, looksLikeRtcm3, scanRtcm3 } from "./rtcm3";
import { type UbxSummary, looksLikeUbx, scanUbx, ubxChecksum } from "./ubx";

/** The kinds the server recognises by content, with its names (GET /file-kinds: frontend/tests/fixtures/
 * file_kinds.json, held equal by tests/frontend/test_file_kind_names.py and tests/fileKinds.test.ts). */
export const SERVER_KINDS = [
  "rinex-obs", "rinex-nav", "ubx", "rtcm3", "dji-mrk", "image", "events", "points", "gcp-list", "survey-metadata",
  "archive", "site-calibration",
] as const;
/** What only this pre-check names: files the server does not take (met files, notes) or does not recognise. */
export const LOCAL_ONLY_KINDS = ["rinex-met", "readme", "unknown"] as const;
export type FileKind = (typeof SERVER_KINDS)[number] | (typeof LOCAL_ONLY_KINDS)[number];

/** Kinds of GNSS observation files (a receiver's log: they have a role, rover or base). */
export const OBSERVATION_KINDS: FileKind[] = ["rinex-obs", "ubx", "rtcm3"];
export const isObservation = (k: FileKind): boolean => OBSERVATION_KINDS.includes(k);
/** What a DJI flight folder holds that is uploaded with it (kind=flight): photos, the MRK, raw logs, nav. */
export const FLIGHT_KINDS: FileKind[] = ["image", "dji-mrk", "rtcm3", "ubx", "rinex-obs", "rinex-nav"];

/** The `kind` of POST /surveys/{id}/uploads (the server's upload hints, GET /file-kinds). */
export const UPLOAD_KINDS = [
  "rover", "base", "nav", "images", "events", "points", "gcp-list", "archive", "survey-metadata", "flight",
  "site-calibration",
] as const;
export type UploadKind = (typeof UPLOAD_KINDS)[number];

export type ObsRole = "rover" | "base";

export interface Sniffed {
  kind: FileKind;
  compression: Compression;
  hatanaka: boolean;
  /** One line for people: "RINEX 3.04 observations, L1+L2, Hatanaka + gzip". */
  description: string;
  rinex?: RinexHeader;
  navFirstMs?: number | null;
  ubx?: UbxSummary;
  rtcm3?: Rtcm3Summary;
  mrk?: MrkSummary;
  image?: { format: "jpeg" | "tiff"; capture: ExifTime | null };
  points?: PointsTable;
  events?: EventsTable;
  gcpList?: GcpListTable;
  /** Role suggested for observation files (from the folder or file name, marker name). */
  roleHint?: ObsRole | null;
  /** Something wrong with the file itself (unsupported packing, unreadable table). */
  problem?: string;
}

/** Bytes read from the start of each file for recognition (and for the tables, which are small). */
export const SNIFF_BYTES = 64 * 1024;

const latin1 = new TextDecoder("latin1");
const utf8 = new TextDecoder("utf-8", { fatal: false });

function isMostlyText(b: Uint8Array): boolean {
  const n = Math.min(b.length, 4096);
  if (n === 0) return false;
  let bad = 0;
  for (let i = 0; i < n; i++) {
    const c = b[i];
    if (c === 0) return false;
    if (c < 9 || (c > 13 && c < 32)) bad++;
  }
  return bad / n < 0.01;
}

export function roleHintFromPath(path: string, header?: RinexHeader | null): ObsRole | null {
  const p = path.toLowerCase();
  const parts = p.split("/");
  for (const part of parts) {
    if (/(^|[^a-z])(rover|drone|uav|uas|aircraft|rov)([^a-z]|$)/.test(part)) return "rover";
    if (/(^|[^a-z])(base|ref|reference|cors|station)([^a-z]|$)/.test(part)) return "base";
  }
  const marker = (header?.markerName ?? "").toLowerCase();
  if (/rov|drone|uav/.test(marker)) return "rover";
  if (/base|ref/.test(marker)) return "base";
  return null;
}

function packing(compression: Compression, hatanaka: boolean): string {
  const parts: string[] = [];
  if (hatanaka) parts.push("Hatanaka");
  if (compression === "gzip") parts.push("gzip");
  if (compression === "compress") parts.push("Unix compress");
  return parts.length ? `, ${parts.join(" + ")}` : "";
}

/**
 * Classify a file from its path, the raw first bytes and (for gzip/.Z) their decompressed start.
 * Pure: the browser glue (sniffFile) reads the bytes.
 */
export function classify(path: string, _raw: Uint8Array, data: Uint8Array, compression: Compression): Sniffed {
  const base: Sniffed = { kind: "unknown", compression, hatanaka: false, description: "not recognised" };
  if (compression === "zip") return { ...base, kind: "archive", description: "zip archive (unpacked on the server)" };
  if (compression === "bzip2" || compression === "xz" || compression === "zstd") {
    return { ...base, description: `${compression} archive`, problem: `${compression} packing is not supported: use zip, gzip or .Z` };
  }
  if (compression !== "none" && data.length === 0) {
    return { ...base, description: `${compression} data`, problem: "the compressed data could not be decoded (corrupt or truncated)" };
  }
  // Binary formats first.
  if (data[0] === 0xff && data[1] === 0xd8 && data[2] === 0xff) {
    return { ...base, kind: "image", description: "JPEG photo", image: { format: "jpeg", capture: exifCaptureTime(data) } };
  }
  const tiffLE = data[0] === 0x49 && data[1] === 0x49 && (data[2] === 0x2a || data[2] === 0x2b) && data[3] === 0x00;
  const tiffBE = data[0] === 0x4d && data[1] === 0x4d && data[2] === 0x00 && (data[3] === 0x2a || data[3] === 0x2b);
  if (tiffLE || tiffBE) {
    return { ...base, kind: "image", description: "TIFF image", image: { format: "tiff", capture: exifCaptureTime(data) } };
  }
  if (!isMostlyText(data)) {
    // UBX and RTCM 3 told apart by which framing covers more of the bytes (a chance B5 62 or D3 inside
    // the other format's frames does not decide it), as the server does
    const ubx = scanUbx(data);
    const ubxBytes = looksLikeUbx(data) ? ubxBytesOf(data) : 0;
    const rtcm3 = scanRtcm3(data);
    if (looksLikeRtcm3(rtcm3, ubxBytes)) {
      const systems = rtcm3.systems.length ? `, ${rtcm3.systems.join("+")}` : "";
      const eph = rtcm3.ephemerides ? ", with ephemerides" : "";
      return {
        ...base, kind: "rtcm3", rtcm3, roleHint: roleHintFromPath(path),
        description: `RTCM 3 log${systems}${eph}${packing(compression, false)}`,
        problem: compression !== "none" ? `${compression}-packed RTCM 3 logs are not accepted: send it unpacked` : undefined,
      };
    }
    if (ubxBytes > 0) {
      return { ...base, kind: "ubx", ubx, roleHint: roleHintFromPath(path), description: `u-blox UBX log${packing(compression, false)}` };
    }
    return base;
  }
  const text = latin1.decode(data);
  const rinex = parseRinexHeader(text);
  if (rinex) {
    const pk = packing(compression, rinex.hatanaka);
    const v = rinex.version ? rinex.version.toFixed(2) : "?";
    if (rinex.type === "obs") {
      const bands = phaseBands(rinex);
      return {
        ...base, kind: "rinex-obs", hatanaka: rinex.hatanaka, rinex, roleHint: roleHintFromPath(path, rinex),
        description: `RINEX ${v} observations${bands.length ? `, ${bands.join("+")}` : ""}${pk}`,
      };
    }
    if (rinex.type === "nav") {
      return {
        ...base, kind: "rinex-nav", rinex, navFirstMs: firstNavRecordMs(text, rinex.version),
        description: `RINEX ${v} navigation${pk}`,
      };
    }
    if (rinex.type === "met") return { ...base, kind: "rinex-met", rinex, description: `RINEX ${v} meteorological data (not used)` };
    return { ...base, description: `RINEX ${v} file of an unknown type` };
  }
  const utext = utf8.decode(data);
  if (looksLikeMrk(utext)) {
    const mrk = parseMrk(utext);
    return {
      ...base, kind: "dji-mrk", mrk, description: `DJI Timestamp.MRK (${mrk.exposures} exposures)`,
      problem: mrk.badLines.length ? `damaged MRK: line ${mrk.badLines[0]} does not read as an exposure` : undefined,
    };
  }
  const cal = siteCalibrationOf(utext);
  if (cal) return { ...base, kind: "site-calibration", description: cal };
  const meta = surveyMetadata(utext);
  if (meta) return { ...base, kind: "survey-metadata", description: `survey metadata${meta.crs ? ` (${meta.crs})` : ""}` };
  // A table cut at SNIFF_BYTES loses its last row: drop the partial line unless the file was read whole.
  if (looksLikeGcpList(utext)) {
    const gcpList = parseGcpList(utext);
    return { ...base, kind: "gcp-list", gcpList, description: `ODM gcp_list (${gcpList.crs}, ${gcpList.measurements} image measurements)` };
  }
  if (looksLikeEventsCsv(utext)) {
    const events = parseEventsCsv(utext);
    return { ...base, kind: "events", events, description: `camera events (${events.count})` };
  }
  if (looksLikePointsCsv(utext)) {
    const points = parsePointsCsv(utext);
    const nc = points.points.filter((p) => p.role === "control").length;
    const nk = points.points.length - nc;
    return {
      ...base, kind: "points", points,
      description: `ground points (${nc} control, ${nk} check)`,
      problem: points.errors.length ? points.errors.slice(0, 3).join("; ") : undefined,
    };
  }
  if (/(^|\/)readme(\.\w+)?$/i.test(path) || /\.(md|txt)$/i.test(path)) {
    return { ...base, kind: "readme", description: "text notes (kept with the survey)" };
  }
  return base;
}

const METADATA_KEYS = ["project_crs", "points_crs", "takeoff_antenna_ecef_m", "receiver", "heights", "crs", "lever_arm_m"];

/** survey.json: a JSON object with at least one of the survey metadata keys. */
/**
 * A site calibration (the datum step applies it: docs/datums.md): the JSON `georef datum calibrate` writes
 * ("format": "georef-site-calibration"), or a CSV of control pairs (a header with local_e_m / local_x ...); its
 * description, or null. The server checks it fully.
 */
export function siteCalibrationOf(text: string): string | null {
  const t = text.trim();
  if (t.startsWith("{")) {
    try {
      const o = JSON.parse(t);
      return o && typeof o === "object" && o.format === "georef-site-calibration"
        ? `site calibration${typeof o.name === "string" && o.name ? ` “${o.name}”` : ""} (${Array.isArray(o.points) ? o.points.length : 0} control points)`
        : null;
    } catch {
      return null;
    }
  }
  const first = t.split(/\r?\n/).find((l) => l.trim() && !l.startsWith("#")) ?? "";
  if (!/(^|[,;\s])local_(e|e_m|x|easting_m)\s*([,;\s]|$)/i.test(first)) return null;
  const rows = t.split(/\r?\n/).filter((l) => l.trim() && !l.startsWith("#")).length - 1;
  return `site calibration control pairs (${rows} points)`;
}

export function surveyMetadata(text: string): { crs: string | null } | null {
  const t = text.trim();
  if (!t.startsWith("{")) return null;
  try {
    const o = JSON.parse(t);
    if (!o || typeof o !== "object" || Array.isArray(o)) return null;
    if (!METADATA_KEYS.some((k) => k in o)) return null;
    return { crs: typeof o.project_crs === "string" ? o.project_crs : typeof o.crs === "string" ? o.crs : null };
  } catch {
    return null;
  }
}

/** Bytes inside valid UBX frames of a buffer. */
function ubxBytesOf(data: Uint8Array): number {
  let n = 0;
  let i = 0;
  while (i + 8 <= data.length) {
    if (data[i] !== 0xb5 || data[i + 1] !== 0x62) {
      i++;
      continue;
    }
    const len = data[i + 4] | (data[i + 5] << 8);
    const end = i + 6 + len;
    if (end + 2 > data.length) break;
    const [a, b] = ubxChecksum(data, i + 2, end);
    if (a === data[end] && b === data[end + 1]) {
      n += len + 8;
      i = end + 2;
    } else i++;
  }
  return n;
}

/** The upload `kind` for a recognised file, or null when it is not sent (a file of a DJI flight folder
 * goes with kind=flight: see flightOf in preflight.ts). */
export function uploadKindOf(s: Sniffed, role: ObsRole | null): UploadKind | null {
  switch (s.kind) {
    case "rinex-obs":
    case "ubx":
    case "rtcm3":
      return role;
    case "dji-mrk":
      return "flight";
    case "rinex-nav":
      return "nav";
    case "image":
      return "images";
    case "events":
      return "events";
    case "points":
      return "points";
    case "gcp-list":
      return "gcp-list";
    case "archive":
      return "archive";
    case "survey-metadata":
      return "survey-metadata";
    case "site-calibration":
      return "site-calibration";
    default:
      return null;
  }
}

/** Read the first bytes of a File (decompressing gzip/.Z) and classify it. */
export async function sniffFile(file: Blob, path: string, bytes = SNIFF_BYTES): Promise<Sniffed> {
  const raw = new Uint8Array(await file.slice(0, bytes).arrayBuffer());
  const { compression, data } = await inflateHead(raw, bytes);
  const s = classify(path, raw, data, compression);
  // Tables are small: when the head held the whole file they are complete; else re-read them whole.
  if ((s.kind === "points" || s.kind === "events" || s.kind === "gcp-list" || s.kind === "dji-mrk") && file.size > bytes && file.size < 32 * 1024 * 1024) {
    const all = new Uint8Array(await file.slice(0, file.size).arrayBuffer());
    const whole = compression === "none" ? all : (await inflateHead(all, 64 * 1024 * 1024)).data;
    return classify(path, all, whole, compression);
  }
  return s;
}
