/**
 * Pre-flight check of a survey folder in the browser, before anything is uploaded: are the rover, the
 * base and the navigation data there, do the rover and base observe at the same time, does every photo
 * have a camera event, are the ground points usable. Pure: takes the recognised files, returns problems.
 */

import type { ObsScan } from "./obsScan";
import type { ObsRole, Sniffed } from "./sniff";

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

  const obs = files.filter((f) => f.sniff.kind === "rinex-obs" || f.sniff.kind === "ubx");
  const rovers = obs.filter((f) => f.role === "rover");
  const bases = obs.filter((f) => f.role === "base");
  const unassigned = obs.filter((f) => f.role !== "rover" && f.role !== "base");
  const navs = files.filter((f) => f.sniff.kind === "rinex-nav");
  const images = files.filter((f) => f.sniff.kind === "image");
  const eventsTables = files.filter((f) => f.sniff.kind === "events");
  const pointsTables = files.filter((f) => f.sniff.kind === "points");
  const archives = files.filter((f) => f.sniff.kind === "archive");
  const unknown = files.filter((f) => f.sniff.kind === "unknown" && !f.sniff.problem);

  if (unassigned.length) {
    add("error", "role_unknown", "Say for each observation file whether it is the drone (rover) or the base station.", unassigned.map((f) => f.path));
  }
  const hasArchive = archives.length > 0;
  if (!rovers.length && !hasArchive) add("error", "missing_rover", "No drone (rover) GNSS observation file: add the drone's RINEX observation or UBX log.");
  if (!bases.length && !hasArchive) add("error", "missing_base", "No base station observation file: PPK needs the base receiver's RINEX observations.");
  if (rovers.length > 1) add("warning", "several_rovers", `${rovers.length} rover files: the server processes them as one flight.`, rovers.map((f) => f.path));

  const ubxNav = obs.some((f) => f.sniff.kind === "ubx" && (f.sniff.ubx?.sfrbx ?? 0) > 0);
  if (!navs.length && !hasArchive) {
    if (ubxNav) add("info", "nav_from_ubx", "No RINEX navigation file: the broadcast ephemerides in the UBX log will be used.");
    else add("error", "missing_nav", "Navigation data missing: add the base station's RINEX navigation file (.nav, .##n, .##p, ...).");
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

  // Camera events for the photos.
  if (images.length) {
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
  } else if (!hasArchive) {
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
  } else if (images.length) {
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
  const obs = files.filter((f) => f.sniff.kind === "rinex-obs" || f.sniff.kind === "ubx");
  for (const f of obs) if (!f.role && f.sniff.roleHint) f.role = f.sniff.roleHint;
  const open = obs.filter((f) => !f.role);
  if (!open.length) return;
  const hasRover = obs.some((f) => f.role === "rover");
  const hasBase = obs.some((f) => f.role === "base");
  if (open.length === 1 && hasRover && !hasBase) open[0].role = "base";
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
