/**
 * The site's design surface (GET/PUT/PATCH /sites/{id}/design) and its progress over the surveys
 * (GET /sites/{id}/design-progress, from the design steps' stored summaries): shapes, the chart's series
 * (net ± 1σ per flight) and the editor's inputs (tolerance, area).
 */

import type { SeriesPoint } from "../components/LineChart";
import type { MapOutline } from "../components/MapView";
import { bboxOf, openRing, outlinesFromGeoJson, ringToGeoJson, selfIntersects, type Ring } from "./geom";

export interface SiteDesign {
  site_id: string;
  filename: string;
  format: "landxml" | "dxf" | "geotiff" | string;
  sha256: string;
  size: number;
  surface_name: string | null;
  described: {
    kind?: string;
    name?: string;
    crs?: string;
    n_points?: number;
    n_triangles?: number;
    height_range_m?: [number, number] | number[];
    notes?: string[];
    /** [xmin, ymin, xmax, ymax] in the site CRS */
    extent?: number[];
  };
  area: { type: "Polygon" | "MultiPolygon"; coordinates: unknown } | null;
  area_m2: number | null;
  tolerance_m: number;
  key: string;
  created_at: string;
  updated_at: string;
  version: number;
}

export interface ProgressEntry {
  survey_id: string;
  survey_name: string;
  flown_at: string | null;
  run_id: string;
  run_number: number;
  cut_m3: number | null;
  fill_m3: number | null;
  net_m3: number | null;
  sigma_m3: { cut_m3?: number; fill_m3?: number; net_m3?: number };
  on_grade_share: number | null;
  on_grade_expected_share?: number | null;
  tolerance_m: number | null;
  area_m2: number | null;
  not_significant_m2?: number | null;
  surface?: string | null;
  warnings: string[];
  /** against the survey before it (null for the first): backend/schemas/designs.DesignChange */
  since_previous?: DesignChange | null;
}

export interface DesignChange {
  previous_survey_id: string;
  previous_survey_name: string;
  days: number | null;
  cut_moved_m3: number | null;
  fill_placed_m3: number | null;
  net_change_m3: number | null;
  sigma_m3: { cut_moved_m3?: number | null; fill_placed_m3?: number | null; net_change_m3?: number | null };
  remaining_cut_m3: number | null;
  remaining_fill_m3: number | null;
  done_share: { cut_m3?: number | null; fill_m3?: number | null };
  /** "surfaces": the two surveys compared cell by cell inside the design area; "totals": from their cut/fill totals */
  method?: "surfaces" | "totals";
  cut_below_design_m3?: number | null;
  fill_above_design_m3?: number | null;
  area_m2?: number | null;
  notes: string[];
  /** the surface-against-surface comparison, computed by a worker and stored (queued / running: the figures are the
   * totals' until it is done; null: not possible, a file missing) */
  surfaces_state?: "queued" | "running" | "succeeded" | "failed" | null;
}

export interface DesignProgress {
  design: { filename: string; format: string; sha256: string; key: string; surface_name: string | null; area_m2: number | null; tolerance_m: number };
  conventions: string;
  surveys: ProgressEntry[];
  not_compared: { survey_id: string; survey_name: string; flown_at: string | null; reason: string }[];
  /** a change between surveys is still being computed by a worker (the API answered 202): ask again later */
  changes_pending?: boolean;
}

/** Design files the server reads (georef_core.design): LandXML, DXF (3DFACE / polyface mesh), GeoTIFF. */
export const DESIGN_FILE_ACCEPT = ".xml,.landxml,.dxf,.tif,.tiff";

/** The chart's points: net ± 1σ (m³) at each flight; surveys without a flight date are left out. */
export function netSeriesPoints(p: DesignProgress): SeriesPoint[] {
  const out: SeriesPoint[] = [];
  for (const e of p.surveys) {
    const t = e.flown_at ? Date.parse(e.flown_at) : NaN;
    if (!Number.isFinite(t) || e.net_m3 === null || e.net_m3 === undefined || !Number.isFinite(e.net_m3)) continue;
    const s = e.sigma_m3?.net_m3;
    out.push({ x: t, y: e.net_m3, err: typeof s === "number" && Number.isFinite(s) ? s : null, label: e.survey_name });
  }
  return out.sort((a, b) => a.x - b.x);
}

/** "63 %" of the area on grade (within ± tolerance), or "–". */
export function formatShare(share: number | null | undefined): string {
  if (share === null || share === undefined || !Number.isFinite(share)) return "–";
  const pct = share * 100;
  return `${pct < 10 && pct > 0 ? pct.toFixed(1) : Math.round(pct)} %`;
}

/**
 * The tolerance typed in centimetres ("5", "2.5") as metres, or an error in words: the server accepts
 * 0 to 10 m; a tolerance of 0 classes nothing on grade, so at least 1 mm.
 */
export function parseToleranceCm(text: string): { value_m: number } | { error: string } {
  const t = text.trim().replace(",", ".");
  if (!t) return { error: "the tolerance is empty: type it in centimetres (e.g. 5)" };
  const v = Number(t);
  if (!Number.isFinite(v)) return { error: `“${text}” is not a number: type the tolerance in centimetres (e.g. 5)` };
  if (v < 0.1) return { error: "the tolerance must be at least 0.1 cm (1 mm)" };
  if (v > 1000) return { error: "the tolerance must be at most 1000 cm (10 m)" };
  return { value_m: Math.round(v * 10) / 1000 };
}

/** The design's extent (site CRS) as a GeoJSON rectangle: a first area when no outline is at hand. */
export function areaFromExtent(extent: number[] | undefined | null): { type: "Polygon"; coordinates: number[][][] } | null {
  if (!extent || extent.length !== 4 || !extent.every(Number.isFinite)) return null;
  const [x0, y0, x1, y1] = extent;
  if (!(x1 > x0 && y1 > y0)) return null;
  const ring: Ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]];
  return ringToGeoJson(ring);
}

/**
 * The area from a GeoJSON file (one polygon or a collection of them: a MultiPolygon), in the site CRS;
 * refused in words when it is in longitude/latitude, self-intersecting, or lies outside the design.
 */
export function areaFromGeoJson(text: string, extent?: number[] | null): { area: { type: "Polygon" | "MultiPolygon"; coordinates: number[][][] | number[][][][] }; parts: number } {
  const outlines = outlinesFromGeoJson(text);
  // O(n²): checked here for hand-made outlines; the server checks every outline (shapely)
  for (const o of outlines) if (o.ring.length <= 2000 && selfIntersects(o.ring)) throw new Error(`“${o.name}” crosses itself: correct the outline`);
  if (extent && extent.length === 4) {
    const bb = bboxOf(outlines.flatMap((o) => o.ring));
    if (bb && (bb.maxX < extent[0] || bb.minX > extent[2] || bb.maxY < extent[1] || bb.minY > extent[3])) {
      throw new Error(`the outline (${bb.minX.toFixed(1)}, ${bb.minY.toFixed(1)} – ${bb.maxX.toFixed(1)}, ${bb.maxY.toFixed(1)}) lies outside the design (${extent.map((v) => v.toFixed(1)).join(", ")}): are both in the site CRS?`);
    }
  }
  const polys = outlines.map((o) => ringToGeoJson(o.ring));
  if (polys.length === 1) return { area: polys[0], parts: 1 };
  return { area: { type: "MultiPolygon", coordinates: polys.map((p) => p.coordinates) }, parts: polys.length };
}

/**
 * The design area (a GeoJSON Polygon or MultiPolygon in the site CRS) as map outlines: one per ring (outer
 * rings and holes alike, each drawn as a line), the first named after the design. Rings with fewer than three
 * distinct corners or a coordinate that is not a number are left out; no area: none.
 */
export function designAreaOutlines(design: Pick<SiteDesign, "area" | "filename"> | null | undefined): MapOutline[] {
  const a = design?.area;
  if (!a || !Array.isArray(a.coordinates)) return [];
  const polys = (a.type === "MultiPolygon" ? a.coordinates : a.type === "Polygon" ? [a.coordinates] : []) as unknown[][][][];
  const out: MapOutline[] = [];
  polys.forEach((poly, i) => {
    (Array.isArray(poly) ? poly : []).forEach((ring, j) => {
      if (!Array.isArray(ring)) return;
      const pts = ring.map((c) => (Array.isArray(c) ? [Number(c[0]), Number(c[1])] : [NaN, NaN]) as [number, number]);
      if (pts.some(([x, y]) => !Number.isFinite(x) || !Number.isFinite(y))) return;
      const r = openRing(pts) as Ring;
      if (r.length < 3) return;
      out.push({ id: `design-area-${i}-${j}`, name: out.length ? "" : `Design area (${design!.filename})`, ring: r, kind: "design" });
    });
  });
  return out;
}

/** "+12.3 ± 0.4" (m³) of a change, or "–" when it is unknown. */
export function formatChange(v: number | null | undefined, sigma?: number | null): string {
  if (v === null || v === undefined || !Number.isFinite(v)) return "–";
  const digits = Math.abs(v) >= 100 ? 0 : 1;
  const s = `${v >= 0 ? "+" : "−"}${Math.abs(v).toFixed(digits)}`;
  return sigma !== null && sigma !== undefined && Number.isFinite(sigma) ? `${s} ± ${sigma.toFixed(digits)}` : s;
}

/** A change's comparison in words: pending while a worker computes it surface against surface (the figures shown
 * meanwhile are the totals'), done, or from the totals (failed, or a file missing). */
export function changeState(c: Pick<DesignChange, "surfaces_state" | "method">): { label: string; pending: boolean } {
  switch (c.surfaces_state) {
    case "queued":
    case "running":
      return { label: "pending: being computed surface against surface (figures from the totals meanwhile)", pending: true };
    case "succeeded":
      return { label: "done: surface against surface", pending: false };
    case "failed":
      return { label: "from the totals: the surface comparison failed", pending: false };
    default:
      return { label: c.method === "surfaces" ? "done: surface against surface" : "from the totals", pending: false };
  }
}

/** How long to wait before asking design-progress again while a change is being computed (the API answered 202):
 * 3 s, doubling, at most 60 s; null when nothing is pending or after `maxPolls` asks (about half an hour). */
export function progressPollDelayMs(p: Pick<DesignProgress, "changes_pending"> | null | undefined, polls: number, maxPolls = 40): number | null {
  if (!p || !p.changes_pending || polls >= maxPolls) return null;
  return Math.min(3000 * 2 ** Math.max(polls, 0), 60000);
}
