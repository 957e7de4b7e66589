/**
 * The small text tables of a survey folder: ground points (gcp/points.csv), camera events (events.csv)
 * and ODM's gcp_list.txt (image measurements of the targets). Parsed leniently, with each problem named.
 */

export type PointRole = "control" | "check";

export interface GroundPoint {
  name: string;
  easting: number;
  northing: number;
  height: number;
  role: PointRole;
}

export interface PointsTable {
  points: GroundPoint[];
  errors: string[];
  hasHeader: boolean;
}

export interface EventsTable {
  images: string[];
  count: number;
  errors: string[];
}

export interface GcpListTable {
  crs: string;
  measurements: number;
  images: string[];
  targets: string[];
  errors: string[];
}

function splitRow(line: string): string[] {
  if (line.includes(",")) return line.split(",").map((s) => s.trim());
  if (line.includes(";")) return line.split(";").map((s) => s.trim());
  if (line.includes("\t")) return line.split("\t").map((s) => s.trim());
  return line.trim().split(/\s+/);
}

function lines(text: string): string[] {
  return text
    .replace(/^\uFEFF/, "")
    .split(/\r?\n/)
    .map((l) => l.trim())
    .filter((l) => l && !l.startsWith("#"));
}

const isNum = (s: string | undefined) => s !== undefined && s !== "" && Number.isFinite(Number(s));

const NAME_COLS = ["name", "point", "id", "label", "target", "gcp"];
const E_COLS = ["easting_m", "easting", "e", "x", "east"];
const N_COLS = ["northing_m", "northing", "n", "y", "north"];
const H_COLS = ["ellipsoidal_height_m", "height_m", "height", "h", "z", "elevation", "elev", "alt", "altitude"];
const ROLE_COLS = ["role", "type", "use", "kind"];

function findCol(header: string[], names: string[]): number {
  const h = header.map((x) => x.toLowerCase().replace(/[\s"']/g, ""));
  for (const n of names) {
    const i = h.indexOf(n);
    if (i >= 0) return i;
  }
  return -1;
}

export function normaliseRole(s: string | undefined): PointRole | null {
  const v = (s ?? "").trim().toLowerCase();
  if (["control", "gcp", "ctrl", "c", "control point"].includes(v)) return "control";
  if (["check", "cp", "chk", "checkpoint", "check point", "k"].includes(v)) return "check";
  return null;
}

/** Ground points: `name,easting_m,northing_m,ellipsoidal_height_m,role` (header optional, role optional). */
export function parsePointsCsv(text: string): PointsTable {
  const rows = lines(text).map(splitRow);
  const out: PointsTable = { points: [], errors: [], hasHeader: false };
  if (!rows.length) {
    out.errors.push("the file is empty");
    return out;
  }
  let cName = 0, cE = 1, cN = 2, cH = 3, cRole = 4;
  let start = 0;
  if (!isNum(rows[0][1])) {
    const hdr = rows[0];
    out.hasHeader = true;
    start = 1;
    cName = findCol(hdr, NAME_COLS);
    cE = findCol(hdr, E_COLS);
    cN = findCol(hdr, N_COLS);
    cH = findCol(hdr, H_COLS);
    cRole = findCol(hdr, ROLE_COLS);
    if (cName < 0 || cE < 0 || cN < 0 || cH < 0) {
      out.errors.push(`header "${hdr.join(",")}" lacks a name, easting, northing or height column`);
      return out;
    }
  }
  const seen = new Set<string>();
  for (let i = start; i < rows.length; i++) {
    const r = rows[i];
    const lineNo = i + 1;
    const name = r[cName];
    if (!name) {
      out.errors.push(`line ${lineNo}: no point name`);
      continue;
    }
    if (!isNum(r[cE]) || !isNum(r[cN]) || !isNum(r[cH])) {
      out.errors.push(`line ${lineNo} (${name}): easting, northing and height must be numbers`);
      continue;
    }
    let role: PointRole = "control";
    if (cRole >= 0 && r[cRole] !== undefined && r[cRole] !== "") {
      const v = normaliseRole(r[cRole]);
      if (!v) {
        out.errors.push(`line ${lineNo} (${name}): role "${r[cRole]}" is neither control nor check`);
        continue;
      }
      role = v;
    }
    if (seen.has(name)) {
      out.errors.push(`line ${lineNo}: point ${name} appears twice`);
      continue;
    }
    seen.add(name);
    out.points.push({ name, easting: +r[cE], northing: +r[cN], height: +r[cH], role });
  }
  return out;
}

/** True when the header row looks like a ground-point table. */
export function looksLikePointsCsv(text: string): boolean {
  const rows = lines(text.slice(0, 4000)).map(splitRow);
  if (rows.length < 1) return false;
  const hdr = rows[0];
  if (!isNum(hdr[1])) {
    return findCol(hdr, NAME_COLS) >= 0 && findCol(hdr, E_COLS) >= 0 && findCol(hdr, N_COLS) >= 0 && findCol(hdr, H_COLS) >= 0;
  }
  // Headerless: name followed by three numbers on (almost) every row.
  const ok = rows.slice(0, 20).filter((r) => r.length >= 4 && !isNum(r[0]) && isNum(r[1]) && isNum(r[2]) && isNum(r[3]));
  return ok.length >= Math.max(1, Math.min(rows.length, 20) - 1);
}

/** Camera events: a header with an image column and a time column (`image,trigger_gps_time_s,...`). */
export function looksLikeEventsCsv(text: string): boolean {
  const first = lines(text.slice(0, 2000))[0];
  if (!first) return false;
  const h = splitRow(first).map((x) => x.toLowerCase());
  return h.some((x) => x.includes("image") || x === "photo" || x === "file") && h.some((x) => x.includes("time") || x === "tow_s" || x.includes("gps"));
}

export function parseEventsCsv(text: string): EventsTable {
  const rows = lines(text).map(splitRow);
  const out: EventsTable = { images: [], count: 0, errors: [] };
  if (!rows.length) return out;
  const hdr = rows[0].map((x) => x.toLowerCase());
  const ci = hdr.findIndex((x) => x.includes("image") || x === "photo" || x === "file");
  const ct = hdr.findIndex((x) => x.includes("time") || x === "tow_s");
  for (let i = 1; i < rows.length; i++) {
    const r = rows[i];
    if (ct >= 0 && !isNum(r[ct])) {
      out.errors.push(`line ${i + 1}: time "${r[ct] ?? ""}" is not a number`);
      continue;
    }
    out.count++;
    if (ci >= 0 && r[ci]) out.images.push(r[ci]);
  }
  return out;
}

const CRS_LINE = /^(EPSG:\d+|\+proj=.*|WGS84 UTM \d{1,2}[NS]|WGS84)$/i;

export function looksLikeGcpList(text: string): boolean {
  const ls = lines(text.slice(0, 4000));
  if (ls.length < 2 || !CRS_LINE.test(ls[0])) return false;
  const r = ls[1].split(/\s+/);
  return r.length >= 6 && r.slice(0, 5).every(isNum);
}

/** ODM gcp_list.txt: a CRS line, then `geo_x geo_y geo_z im_x im_y image_name [gcp_name]` rows. */
export function parseGcpList(text: string): GcpListTable {
  const ls = lines(text);
  const out: GcpListTable = { crs: ls[0] ?? "", measurements: 0, images: [], targets: [], errors: [] };
  if (!CRS_LINE.test(out.crs)) out.errors.push(`first line "${out.crs}" is not a CRS (EPSG:code, +proj=..., WGS84 UTM zone)`);
  const images = new Set<string>();
  const targets = new Set<string>();
  for (let i = 1; i < ls.length; i++) {
    const r = ls[i].split(/\s+/);
    if (r.length < 6 || !r.slice(0, 5).every(isNum)) {
      out.errors.push(`line ${i + 1}: expected geo_x geo_y geo_z im_x im_y image_name [gcp_name]`);
      continue;
    }
    out.measurements++;
    images.add(r[5]);
    targets.add(r[6] ?? `${r[0]},${r[1]}`);
  }
  out.images = [...images];
  out.targets = [...targets];
  return out;
}
