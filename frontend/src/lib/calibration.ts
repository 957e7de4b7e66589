/**
 * The site calibration (localisation) the datum step applied, as its summary holds it
 * (georef_core/datums/site_calibration.SiteCalibration.summary): parameters in words and the residual per
 * control point (given local minus calibrated, metres).
 */

export interface CalibrationResidual {
  name: string;
  use: string;
  dE_m: number | null;
  dN_m: number | null;
  dH_m: number | null;
}

export interface CalibrationSummary {
  source?: string;
  name?: string;
  crs?: string;
  height_datum?: string;
  horizontal: { scale: number; scale_ppm: number; rotation_deg: number; origin_source_m?: number[]; origin_local_m?: number[] };
  vertical: { model: string; constant_m: number; slope_north: number; slope_east: number };
  sigmas?: Record<string, number | null>;
  residuals: CalibrationResidual[];
  statistics?: { rms_horizontal_m?: number | null; max_horizontal_m?: number | null; rms_vertical_m?: number | null; max_vertical_m?: number | null };
}

const num = (v: unknown): number | null => (typeof v === "number" && Number.isFinite(v) ? v : null);

/** The calibration of a datum step's summary, or null (none applied, or a summary of another shape). */
export function calibrationOf(summary: Record<string, any> | null | undefined): CalibrationSummary | null {
  const c = summary?.calibration;
  if (!c || typeof c !== "object" || !c.horizontal || !c.vertical || !Array.isArray(c.residuals)) return null;
  if (num(c.horizontal.scale) === null) return null;
  return {
    ...c,
    residuals: c.residuals
      .filter((r: any) => r && typeof r.name === "string")
      .map((r: any) => ({ name: r.name, use: String(r.use ?? "hv"), dE_m: num(r.dE_m), dN_m: num(r.dN_m), dH_m: num(r.dH_m) })),
  };
}

/** A residual in millimetres with its sign ("+4.2"), or "–" where the point was not used in that direction. */
export function formatResidualMm(v: number | null): string {
  if (v === null) return "–";
  const mm = v * 1000;
  return `${mm >= 0 ? "+" : "−"}${Math.abs(mm).toFixed(1)}`;
}

/** The calibration's parameters in words, one line each. */
export function calibrationParameterLines(c: CalibrationSummary): string[] {
  const h = c.horizontal, v = c.vertical;
  const sig = c.sigmas ?? {};
  const pm = (s: number | null | undefined, f: (x: number) => string) => (num(s) !== null ? ` ± ${f(s as number)}` : "");
  const lines = [
    `scale ${h.scale.toFixed(9)} (${h.scale_ppm >= 0 ? "+" : "−"}${Math.abs(h.scale_ppm).toFixed(1)} ppm${pm(sig.scale, (s) => `${(s * 1e6).toFixed(1)} ppm`)}), rotation ${h.rotation_deg >= 0 ? "+" : "−"}${Math.abs(h.rotation_deg).toFixed(6)}°${pm(sig.rotation_deg, (s) => `${s.toFixed(6)}°`)}`,
  ];
  if (h.origin_source_m?.length === 2 && h.origin_local_m?.length === 2) {
    lines.push(`centroid E ${h.origin_source_m[0].toFixed(3)} N ${h.origin_source_m[1].toFixed(3)} → e ${h.origin_local_m[0].toFixed(3)} n ${h.origin_local_m[1].toFixed(3)}`);
  }
  if (v.model === "none") lines.push("vertical: none (no vertical control point)");
  else {
    const slopes = v.model === "inclined plane" ? `, slope N ${(v.slope_north * 1e6).toFixed(1)} ppm, slope E ${(v.slope_east * 1e6).toFixed(1)} ppm` : "";
    lines.push(`vertical (${v.model}): shift ${v.constant_m >= 0 ? "+" : "−"}${Math.abs(v.constant_m).toFixed(4)} m${pm(sig.constant_m, (s) => `${s.toFixed(4)} m`)}${slopes}`);
  }
  const st = c.statistics ?? {};
  const mm = (x: number | null | undefined) => (num(x) !== null ? `${((x as number) * 1000).toFixed(1)} mm` : "n/a");
  lines.push(`residuals RMS horizontal ${mm(st.rms_horizontal_m)}, vertical ${mm(st.rms_vertical_m)}; largest ${mm(st.max_horizontal_m)} / ${mm(st.max_vertical_m)}`);
  return lines;
}

/** The site's stored calibration (GET /sites/{id}/calibration: backend/schemas/calibrations.SiteCalibrationOut). */
export interface SiteCalibrationOut {
  site_id: string;
  name: string;
  source_name: string;
  crs: string;
  height_datum: string;
  summary: CalibrationSummary;
  document: Record<string, unknown>;
  set_by: string | null;
  created_at: string;
  updated_at: string;
  version: number;
}

/** The body of PUT /sites/{id}/calibration from a file the user picked: a calibration JSON document (what
 * `georef datum calibrate` writes) or a CSV of control pairs (solved by the server in the site CRS and datum).
 * Read by content, as the server and the survey upload do. Throws with the reason for anything else. */
export function siteCalibrationBody(filename: string, text: string): { document?: Record<string, unknown>; pairs_csv?: string; source_name: string } {
  const t = text.replace(/^\uFEFF/, "").trimStart();
  if (!t) throw new Error("the file is empty");
  if (t.startsWith("{")) {
    let doc: unknown;
    try {
      doc = JSON.parse(t);
    } catch (e) {
      throw new Error(`not valid JSON (${(e as Error).message})`);
    }
    if (!doc || typeof doc !== "object" || (doc as any).format !== "georef-site-calibration") {
      throw new Error("a JSON file that is not a site calibration (its format is not georef-site-calibration)");
    }
    return { document: doc as Record<string, unknown>, source_name: filename };
  }
  const head = t.split(/\r?\n/, 1)[0].toLowerCase().split(/[,;\t]/).map((c) => c.trim());
  if (!head.some((c) => c.startsWith("local_"))) {
    throw new Error("neither a calibration JSON nor a CSV of control pairs (name, easting_m, northing_m, height_m, local_e_m, local_n_m, local_h_m)");
  }
  return { pairs_csv: t, source_name: filename };
}
