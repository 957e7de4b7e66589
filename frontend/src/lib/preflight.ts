/**
 * Pre-flight check of a survey folder in the browser, before anything is uploaded: are the rover, the
 * base and the navigation data there, do the rover and base observe at the same time, does every photo
 * have a camera event, are the ground points usable. Pure: takes the recognised files, returns problems.
 *
 * DJI flight folders (a Timestamp.MRK beside its photos and the aircraft's raw log *_PPKRAW.bin, several
 * after battery swaps) are found with markFlights: their files are uploaded together (kind=flight, with
 * the folder), the raw log is the rover's and the MRK gives the camera events. Several rover or base
 * files are joined in time order by the server. The server's check is the full one (it reads whole files).
 */

import type { ObsScan } from "./obsScan";
import { FLIGHT_KINDS, type ObsRole, type Sniffed, isObservation } from "./sniff";

export type Severity = "error" | "warning" | "info";

export interface Problem {
  severity: Severity;
  code: string;
  message: string;
  files: string[];
}

export interface CheckedFile {
  path: string;
  size: number;
  sniff: Sniffed;
  role: ObsRole | null;
  scan?: ObsScan | null;
  /** The DJI flight folder the file belongs to (relative path of the folder holding its MRK). */
  flight?: string | null;
}

export function folderOf(path: string): string {
  const k = path.lastIndexOf("/");
  return k < 0 ? "" : path.slice(0, k);
}

/**
 * Find the DJI flight folders (folders holding a Timestamp.MRK) and mark their photos, MRK, raw logs and
 * navigation files with it; the raw logs are the rover's. Returns the flight folders found.
 */
export function markFlights(files: CheckedFile[]): string[] {
  const flights = [...new Set(files.filter((f) => f.sniff.kind === "dji-mrk").map((f) => folderOf(f.path)))].sort();
  for (const f of files) {
    const d = folderOf(f.path);
    if (flights.includes(d) && FLIGHT_KINDS.includes(f.sniff.kind)) {
      f.flight = d;
      if (isObservation(f.sniff.kind)) f.role = "rover";
    } else f.flight = null;
  }
  return flights;
}

interface FlightGroup {
  folder: string;
  mrks: CheckedFile[];
  photos: CheckedFile[];
  logs: CheckedFile[];
}

function flightGroups(files: CheckedFile[]): FlightGroup[] {
  const out = new Map<string, FlightGroup>();
  for (const f of files) {
    if (!f.flight) continue;
    const g = out.get(f.flight) ?? { folder: f.flight, mrks: [], photos: [], logs: [] };
    if (f.sniff.kind === "dji-mrk") g.mrks.push(f);
    else if (f.sniff.kind === "image") g.photos.push(f);
    else if (isObservation(f.sniff.kind)) g.logs.push(f);
    out.set(f.flight, g);
  }
  return [...out.values()].sort((a, b) => (a.mrks[0]?.sniff.mrk?.firstMs ?? 0) - (b.mrks[0]?.sniff.mrk?.firstMs ?? 0));
}

const plural = (n: number, one: string, many = `${one}s`) => `${n} ${n === 1 ? one : many}`;
const KIND_WORDS: Record<string, [string, string]> = { "rinex-obs": ["RINEX file", "RINEX files"], ubx: ["UBX log", "UBX logs"], rtcm3: ["RTCM 3 log", "RTCM 3 logs"] };
const ROVER_WORDS: Record<string, [string, string]> = { "rinex-obs": ["RINEX rover file", "RINEX rover files"], ubx: ["UBX rover log", "UBX rover logs"], rtcm3: ["RTCM 3 rover log", "RTCM 3 rover logs"] };

function roverPhrase(fs: CheckedFile[]): string {
  const kinds = [...new Set(fs.map((f) => f.sniff.kind))];
  if (kinds.length === 1 && ROVER_WORDS[kinds[0]]) {
    const [one, many] = ROVER_WORDS[kinds[0]];
    return fs.length === 1 ? one : `${fs.length} ${many}`;
  }
  return `${fs.length} rover files`;
}

function basePhrase(fs: CheckedFile[]): string {
  const kinds = [...new Set(fs.map((f) => f.sniff.kind))];
  if (kinds.length === 1 && KIND_WORDS[kinds[0]]) return `base: ${plural(fs.length, ...KIND_WORDS[kinds[0]])}`;
  return `base: ${fs.length} files`;
}

/** Whether a receiver log carries ephemerides (in the part read). */
function hasEphemerides(f: CheckedFile): boolean {
  return (f.sniff.rtcm3?.ephemerides ?? 0) > 0 || (f.sniff.kind === "ubx" && (f.sniff.ubx?.sfrbx ?? 0) > 0);
}

/** The rover files the server will use: the DJI flights' raw logs, else the files given the rover role. */
function roverFiles(files: CheckedFile[]): CheckedFile[] {
  const logs = files.filter((f) => f.flight && isObservation(f.sniff.kind));
  return logs.length ? logs : files.filter((f) => !f.flight && isObservation(f.sniff.kind) && f.role === "rover");
}

/** One line naming what was found: "2 flights, 419 photos, MRK 419 exposures, RTCM 3 rover log, base: 3 RINEX files, no navigation file needed". */
export function summarise(files: CheckedFile[]): string {
  const flights = flightGroups(files).filter((g) => g.mrks.length);
  const images = files.filter((f) => f.sniff.kind === "image");
  const rovers = roverFiles(files);
  const bases = files.filter((f) => !f.flight && isObservation(f.sniff.kind) && f.role === "base");
  const navs = files.filter((f) => f.sniff.kind === "rinex-nav");
  const parts: string[] = [];
  if (flights.length) parts.push(plural(flights.length, "flight"));
  parts.push(images.length ? plural(images.length, "photo") : "no photos");
  if (flights.length) parts.push(`MRK ${flights.reduce((n, g) => n + g.mrks.reduce((m, f) => m + (f.sniff.mrk?.exposures ?? 0), 0), 0)} exposures`);
  parts.push(rovers.length ? roverPhrase(rovers) : "no rover log");
  parts.push(bases.length ? basePhrase(bases) : "no base");
  const observations = files.some((f) => isObservation(f.sniff.kind));
  if (!observations && images.length) parts.push("photo positions only (no PPK)");
  else if (navs.length) parts.push(`navigation: ${plural(navs.length, "RINEX file")}`);
  else if ([...rovers, ...bases].some(hasEphemerides)) parts.push("no navigation file needed");
  else parts.push("no navigation file");
  return parts.join(", ");
}

export interface TimeSpan {
  firstMs: number;
  lastMs: number;
}

/** Observation time span of a file from its scan, else its header (null when neither says). */
export function spanOf(f: CheckedFile): TimeSpan | null {
  const first = f.scan?.firstMs ?? f.sniff.rinex?.firstObsMs ?? f.sniff.ubx?.firstMs ?? null;
  const last = f.scan?.lastMs ?? f.sniff.rinex?.lastObsMs ?? f.sniff.ubx?.lastMs ?? null;
  if (first === null || last === null) return null;
  return { firstMs: first, lastMs: last };
}

export function isoUtc(ms: number): string {
  return new Date(ms).toISOString().replace("T", " ").replace(/\.\d+Z$/, "").replace("Z", "");
}

function fmtDuration(s: number): string {
  s = Math.abs(s);
  if (s < 120) return `${Math.round(s)} s`;
  if (s < 7200) return `${Math.round(s / 60)} min`;
  return `${(s / 3600).toFixed(1)} h`;
}

/** Overlap of two spans in seconds (negative: the gap between them). */
export function overlapS(a: TimeSpan, b: TimeSpan): number {
  return (Math.min(a.lastMs, b.lastMs) - Math.max(a.firstMs, b.firstMs)) / 1000;
}

/** Tolerance between a photo's EXIF clock and the GNSS time (camera clocks drift; GPS-UTC leap seconds). */
export const EXIF_TIME_TOLERANCE_S = 120;

export function preflight(files: CheckedFile[]): Problem[] {
  const out: Problem[] = [];
  const add = (severity: Severity, code: string, message: string, fs: string[] = []) => out.push({ severity, code, message, files: fs });

  for (const f of files) if (f.sniff.problem) add(f.sniff.kind === "unknown" ? "error" : "error", "bad_file", `${f.path}: ${f.sniff.problem}`, [f.path]);

  const obs = files.filter((f) => isObservation(f.sniff.kind) && !f.flight);
  const flights = flightGroups(files);
  const rovers = roverFiles(files);
  const bases = obs.filter((f) => f.role === "base");
  const unassigned = obs.filter((f) => f.role !== "rover" && f.role !== "base");
  const navs = files.filter((f) => f.sniff.kind === "rinex-nav");
  const images = files.filter((f) => f.sniff.kind === "image" && !f.flight);
  const flightPhotos = files.filter((f) => f.sniff.kind === "image" && f.flight);
  const eventsTables = files.filter((f) => f.sniff.kind === "events");
  const pointsTables = files.filter((f) => f.sniff.kind === "points");
  const archives = files.filter((f) => f.sniff.kind === "archive");
  const unknown = files.filter((f) => f.sniff.kind === "unknown" && !f.sniff.problem);

  if (unassigned.length) {
    add("error", "role_unknown", "Say for each observation file whether it is the drone (rover) or the base station.", unassigned.map((f) => f.path));
  }
  const hasArchive = archives.length > 0;
  // photos alone (RTK-tagged or with EXIF GPS), no receiver log at all: the server skips the PPK and
  // georeferences on the photos' own positions
  const photosOnly = !hasArchive && !rovers.length && !obs.length && (images.length + flightPhotos.length) > 0;
  if (photosOnly) {
    add("warning", "photos_only", "No raw GNSS log and no base station: no PPK; the photos' own positions (RTK tags or EXIF GPS) georeference the survey, to their accuracy. For PPK add the aircraft's raw log (*_PPKRAW.bin) and the base observations.");
  } else if (!rovers.length && !hasArchive) {
    add("error", "missing_rover", flights.length
      ? "No drone raw GNSS log in the flight folders: add the aircraft's *_PPKRAW.bin (or its RINEX observation file)."
      : "No drone (rover) GNSS observation file: add the drone's RINEX observation, UBX or RTCM 3 log.");
  }
  if (!bases.length && !hasArchive && !photosOnly) add("error", "missing_base", "No base station observation file: PPK needs the base receiver's observations (RINEX, UBX or RTCM 3).");
  if (rovers.length > 1) add("info", "rovers_joined", `${rovers.length} rover files: joined in time order (flights after battery swaps).`, rovers.map((f) => f.path));
  if (bases.length > 1) add("info", "bases_joined", `${bases.length} base files: joined in time order (hourly files, a log split by restarts); the server names the gaps.`, bases.map((f) => f.path));

  const ubxNav = [...rovers, ...bases].some((f) => f.sniff.kind === "ubx" && (f.sniff.ubx?.sfrbx ?? 0) > 0);
  const rtcmEph = [...rovers, ...bases].filter((f) => f.sniff.kind === "rtcm3" && (f.sniff.rtcm3?.ephemerides ?? 0) > 0);
  const rtcmNoEph = rovers.filter((f) => f.sniff.kind === "rtcm3" && !(f.sniff.rtcm3?.ephemerides ?? 0));
  if (!navs.length && !hasArchive && !photosOnly) {
    if (ubxNav) add("info", "nav_from_ubx", "No RINEX navigation file: the broadcast ephemerides in the UBX log will be used.");
    else if (rtcmEph.length) add("info", "nav_from_rtcm3", `No RINEX navigation file: the ephemerides in ${rtcmEph.map((f) => f.path.split("/").pop()).join(", ")} will be used.`, rtcmEph.map((f) => f.path));
    else if (rtcmNoEph.length) {
      // only the head of the log was read: the server reads it whole and says whether it carries any
      add("warning", "nav_unknown",
        `No navigation file, and no ephemerides in the first part of ${rtcmNoEph.map((f) => f.path.split("/").pop()).join(", ")}: the server checks the whole log; a PPKRAW without ephemerides needs the RINEX navigation file of the day.`,
        rtcmNoEph.map((f) => f.path));
    } else add("error", "missing_nav", "Navigation data missing: add the base station's RINEX navigation file (.nav, .##n, .##p, ...).");
  }

  // DJI flights: exposures against photos (the server matches them by photo number and checks the times)
  for (const g of flights) {
    if (!g.mrks.length) continue;
    if (g.mrks.length > 1) {
      add("error", "several_mrk", `${g.folder} holds ${g.mrks.length} Timestamp.MRK files: keep each flight in its own folder.`, g.mrks.map((f) => f.path));
      continue;
    }
    const exposures = g.mrks[0].sniff.mrk?.exposures ?? 0;
    if (exposures !== g.photos.length) {
      add("warning", "mrk_photos",
        `${g.mrks[0].path}: ${exposures} exposures but ${g.photos.length} photos in ${g.folder || "the folder"}${exposures > g.photos.length ? " (deleted photos?)" : ": the MRK may not belong to these photos"}.`,
        [g.mrks[0].path]);
    }
  }

  // Time overlap between every rover and base file.
  for (const r of rovers) {
    const rs = spanOf(r);
    for (const b of bases) {
      const bs = spanOf(b);
      if (!rs || !bs) {
        add("info", "overlap_unknown", `The times of ${!rs ? r.path : b.path} are not in its header; the server checks the overlap.`, [r.path, b.path]);
        continue;
      }
      const ov = overlapS(rs, bs);
      const roverS = (rs.lastMs - rs.firstMs) / 1000;
      if (ov <= 0) {
        add("error", "no_overlap",
          `No overlap between rover and base times: rover ${isoUtc(rs.firstMs)} - ${isoUtc(rs.lastMs)}, base ${isoUtc(bs.firstMs)} - ${isoUtc(bs.lastMs)} (${fmtDuration(ov)} apart).`,
          [r.path, b.path]);
      } else if (roverS > 0 && ov < roverS - 1) {
        const startGap = Math.max(0, (bs.firstMs - rs.firstMs) / 1000);
        const endGap = Math.max(0, (rs.lastMs - bs.lastMs) / 1000);
        const pct = Math.round((100 * ov) / roverS);
        add("warning", "partial_overlap",
          `The base covers ${pct} % of the rover time (${startGap > 0 ? `${fmtDuration(startGap)} missing at the start` : ""}${startGap > 0 && endGap > 0 ? ", " : ""}${endGap > 0 ? `${fmtDuration(endGap)} missing at the end` : ""}).`,
          [r.path, b.path]);
      }
    }
  }

  // Navigation data far from the flight (broadcast ephemerides are valid for hours, a file covers a day).
  const roverSpan = rovers.map(spanOf).find((s) => s) ?? null;
  for (const n of navs) {
    const t = n.sniff.navFirstMs;
    if (t == null || !roverSpan) continue;
    if (t > roverSpan.lastMs + 4 * 3600e3 || t < roverSpan.firstMs - 30 * 3600e3) {
      add("warning", "nav_time", `${n.path} starts ${isoUtc(t)}, far from the flight (${isoUtc(roverSpan.firstMs)}): is it from the right day?`, [n.path]);
    }
  }

  // Camera events for the photos (a DJI flight's photos have theirs in the MRK).
  if (images.length && !photosOnly) {
    const listed = new Set<string>();
    for (const e of eventsTables) for (const im of e.sniff.events?.images ?? []) listed.add(im.split(/[\\/]/).pop()!.toLowerCase());
    const rinexEvents = rovers.reduce((n, r) => n + (r.scan?.events ?? 0), 0);
    const eventsUnknown = rovers.some((r) => r.scan?.events == null);
    if (eventsTables.length && listed.size) {
      const missing = images.filter((im) => !listed.has(im.path.split("/").pop()!.toLowerCase()));
      if (missing.length) {
        add("warning", "images_without_events",
          `${missing.length} of ${images.length} images have no camera event in ${eventsTables[0].path}: they are positioned from the image time stamps.`,
          missing.slice(0, 50).map((f) => f.path));
      }
    } else if (!eventsUnknown && rinexEvents === 0) {
      add("warning", "images_without_events",
        `${images.length} images but no camera events (no events.csv, no event records in the rover file): image positions come from the photo time stamps, less accurate.`,
        rovers.map((r) => r.path));
    } else if (!eventsUnknown && rinexEvents < images.length) {
      add("warning", "images_without_events",
        `${images.length} images but only ${rinexEvents} camera events in the rover file: ${images.length - rinexEvents} images have no event.`,
        rovers.map((r) => r.path));
    } else if (!eventsUnknown && rinexEvents > images.length) {
      add("info", "extra_events", `${rinexEvents} camera events for ${images.length} images: the server matches them by time.`);
    }
    // Photo clocks against the flight.
    if (roverSpan) {
      const outside = images.filter((im) => {
        const c = im.sniff.image?.capture;
        if (!c) return false;
        return c.ms < roverSpan.firstMs - EXIF_TIME_TOLERANCE_S * 1000 || c.ms > roverSpan.lastMs + EXIF_TIME_TOLERANCE_S * 1000;
      });
      if (outside.length) {
        add("warning", "images_outside_flight",
          `${outside.length} images were taken (EXIF time) outside the rover's observation time ${isoUtc(roverSpan.firstMs)} - ${isoUtc(roverSpan.lastMs)}: wrong flight or camera clock?`,
          outside.slice(0, 50).map((f) => f.path));
      }
    }
  } else if (!hasArchive && !flightPhotos.length && !images.length) {
    add("info", "no_images", "No photos: only the GNSS trajectory will be computed.");
  }

  // Ground points.
  if (pointsTables.length) {
    for (const p of pointsTables) {
      const t = p.sniff.points!;
      if (!t.points.length) add("error", "points_empty", `${p.path}: no usable point (${t.errors[0] ?? "empty"}).`, [p.path]);
      else if (!t.points.some((x) => x.role === "check")) {
        add("warning", "no_check_points", `${p.path}: no check points (role "check"): the accuracy cannot be verified independently.`, [p.path]);
      }
    }
  } else if (images.length || flightPhotos.length) {
    add("info", "no_points", "No ground points: accuracy is reported from GNSS alone (no check-point residuals).");
  }
  if (unknown.length) add("info", "unrecognised", `${unknown.length} file(s) not recognised; they will not be uploaded.`, unknown.map((f) => f.path));

  const order: Record<Severity, number> = { error: 0, warning: 1, info: 2 };
  return out.sort((a, b) => order[a.severity] - order[b.severity]);
}

/**
 * Give every observation file a role: the folder/marker hint when there is one; otherwise, between two
 * files, the one with camera events or the shorter span is the rover (the base logs before and after).
 */
export function assignRoles(files: CheckedFile[]): void {
  const obs = files.filter((f) => isObservation(f.sniff.kind) && !f.flight);
  for (const f of obs) if (!f.role && f.sniff.roleHint) f.role = f.sniff.roleHint;
  const open = obs.filter((f) => !f.role);
  if (!open.length) return;
  const flightLogs = files.some((f) => f.flight && isObservation(f.sniff.kind));
  const hasRover = obs.some((f) => f.role === "rover") || flightLogs;
  const hasBase = obs.some((f) => f.role === "base");
  // the DJI flights carry the drone's logs: every other observation file is the base's (hourly files...)
  if (flightLogs && !hasBase) for (const f of open) f.role = "base";
  else if (open.length === 1 && hasRover && !hasBase) open[0].role = "base";
  else if (open.length === 1 && hasBase && !hasRover) open[0].role = "rover";
  else if (open.length === 2 && !hasRover && !hasBase) {
    const [a, b] = open;
    const ea = a.scan?.events ?? 0, eb = b.scan?.events ?? 0;
    const sa = spanOf(a), sb = spanOf(b);
    let rover: CheckedFile | null = null;
    if (ea > 0 && eb === 0) rover = a;
    else if (eb > 0 && ea === 0) rover = b;
    else if (a.sniff.kind === "ubx" && b.sniff.kind !== "ubx") rover = a;
    else if (b.sniff.kind === "ubx" && a.sniff.kind !== "ubx") rover = b;
    else if (sa && sb && sa.lastMs - sa.firstMs !== sb.lastMs - sb.firstMs) rover = sa.lastMs - sa.firstMs < sb.lastMs - sb.firstMs ? a : b;
    if (rover) {
      rover.role = "rover";
      (rover === a ? b : a).role = "base";
    }
  }
}
