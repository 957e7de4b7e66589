/**
 * Check-point residual tables: statistics (mean, sample std, RMSE per axis; horizontal and 3D),
 * formatting in the right unit, the colour class against the site's tolerance, and sorting.
 * d = estimated - surveyed, metres, project CRS axes (easting, northing, height).
 */

export interface ResidualPoint {
  name: string;
  role: string;
  dx_m: number;
  dy_m: number;
  dz_m: number;
  d3_m?: number;
  n_images?: number;
  easting_m?: number;
  northing_m?: number;
  note?: string;
}

export interface AxisStats {
  mean: number;
  std: number | null;
  rmse: number;
  maxAbs: number;
}

export interface ResidualStats {
  n: number;
  dx: AxisStats;
  dy: AxisStats;
  dz: AxisStats;
  horizontal: { rmse: number; max: number };
  d3: { mean: number; std: number | null; rmse: number; max: number };
}

export function d3Of(p: ResidualPoint): number {
  return Math.hypot(p.dx_m, p.dy_m, p.dz_m);
}

/** The statistics as the georef step wrote them in residuals.json and the API serves them ("stats": the
 * one definition, georef_core.adjustment.residual_table.residual_statistics: mean, sample std (n - 1), RMSE,
 * max per axis; horizontal; |d|). The browser shows them; it does not compute its own. */
export interface ServedAxis { mean_m: number; std_m: number | null; rmse_m: number; max_abs_m: number }
export interface ServedStats {
  n: number;
  dx?: ServedAxis;
  dy?: ServedAxis;
  dz?: ServedAxis;
  horizontal?: { rmse_m: number; max_m: number };
  "3d"?: { mean_m: number; std_m: number | null; rmse_m: number; max_m: number };
}

const axisOf = (a: ServedAxis): AxisStats => ({ mean: a.mean_m, std: a.std_m, rmse: a.rmse_m, maxAbs: a.max_abs_m });

/** The served statistics in the shape the views use (null when the table has no point). */
export function statsFromServed(s: ServedStats | null | undefined): ResidualStats | null {
  if (!s || !s.n || !s.dx || !s.dy || !s.dz || !s.horizontal || !s["3d"]) return null;
  const d3 = s["3d"];
  return {
    n: s.n, dx: axisOf(s.dx), dy: axisOf(s.dy), dz: axisOf(s.dz),
    horizontal: { rmse: s.horizontal.rmse_m, max: s.horizontal.max_m },
    d3: { mean: d3.mean_m, std: d3.std_m, rmse: d3.rmse_m, max: d3.max_m },
  };
}

export type Unit = "m" | "cm" | "mm";

/** A length in the chosen unit with a sensible number of decimals (null/NaN: an en dash). */
export function formatLength(m: number | null | undefined, unit: Unit = "cm", signed = false): string {
  if (m === null || m === undefined || !Number.isFinite(m)) return "–";
  const f = unit === "m" ? 1 : unit === "cm" ? 100 : 1000;
  const dec = unit === "m" ? 3 : unit === "cm" ? 1 : 0;
  const v = m * f;
  const s = v.toFixed(dec);
  const z = Number(s) === 0 ? (0).toFixed(dec) : s; // no "-0.0"
  return signed && Number(z) > 0 ? `+${z}` : z;
}

export interface Tolerance {
  horizontal_m: number;
  vertical_m: number;
}

export const DEFAULT_TOLERANCE: Tolerance = { horizontal_m: 0.03, vertical_m: 0.05 };

export type ToleranceClass = "ok" | "warn" | "bad";

/** ok: within tolerance; warn: within 1.5x; bad: beyond. */
export function classify(valueAbs: number, tol: number): ToleranceClass {
  const a = Math.abs(valueAbs);
  if (a <= tol) return "ok";
  if (a <= 1.5 * tol) return "warn";
  return "bad";
}

/** The class of a point: the worse of its horizontal and vertical residuals against the tolerance. */
export function pointClass(p: ResidualPoint, tol: Tolerance): ToleranceClass {
  const h = classify(Math.hypot(p.dx_m, p.dy_m), tol.horizontal_m);
  const v = classify(p.dz_m, tol.vertical_m);
  const rank = { ok: 0, warn: 1, bad: 2 } as const;
  return rank[h] >= rank[v] ? h : v;
}

export type SortKey = "name" | "role" | "dx_m" | "dy_m" | "dz_m" | "d3_m" | "n_images";

/** Sorted copy; numbers by absolute value (the size of the error matters, not its sign), names naturally. */
export function sortResiduals(rows: ResidualPoint[], key: SortKey, descending: boolean): ResidualPoint[] {
  const val = (r: ResidualPoint): number | string => {
    if (key === "name" || key === "role") return r[key];
    if (key === "d3_m") return r.d3_m ?? d3Of(r);
    if (key === "n_images") return r.n_images ?? 0;
    return Math.abs(r[key]);
  };
  const coll = new Intl.Collator(undefined, { numeric: true, sensitivity: "base" });
  const out = [...rows].sort((a, b) => {
    const va = val(a), vb = val(b);
    const c = typeof va === "string" ? coll.compare(va, vb as string) : (va as number) - (vb as number);
    return descending ? -c : c;
  });
  return out;
}

/** A residual table as CSV text (what the browser offers to save), statistics rows after the points. */
export function residualsCsv(rows: ResidualPoint[], st: ResidualStats | null): string {
  const f = (v: number | null | undefined) => (v === null || v === undefined ? "" : v.toFixed(4));
  const lines = ["point,role,dx_m,dy_m,dz_m,d3_m"];
  for (const r of rows) lines.push([r.name, r.role, f(r.dx_m), f(r.dy_m), f(r.dz_m), f(r.d3_m ?? d3Of(r))].join(","));
  if (st) {
    lines.push(["mean", "", f(st.dx.mean), f(st.dy.mean), f(st.dz.mean), f(st.d3.mean)].join(","));
    lines.push(["std", "", f(st.dx.std), f(st.dy.std), f(st.dz.std), f(st.d3.std)].join(","));
    lines.push(["rmse", "", f(st.dx.rmse), f(st.dy.rmse), f(st.dz.rmse), f(st.d3.rmse)].join(","));
  }
  return lines.join("\n") + "\n";
}
