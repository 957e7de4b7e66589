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

function axis(v: number[]): AxisStats {
  const n = v.length;
  const mean = v.reduce((a, b) => a + b, 0) / n;
  const std = n > 1 ? Math.sqrt(v.reduce((a, b) => a + (b - mean) ** 2, 0) / (n - 1)) : null;
  const rmse = Math.sqrt(v.reduce((a, b) => a + b * b, 0) / n);
  const maxAbs = v.reduce((a, b) => Math.max(a, Math.abs(b)), 0);
  return { mean, std, rmse, maxAbs };
}

/** Statistics of the rows (null when there are none). Same definitions as georef_core's residual table. */
export function residualStats(rows: ResidualPoint[]): ResidualStats | null {
  if (!rows.length) return null;
  const dx = axis(rows.map((r) => r.dx_m));
  const dy = axis(rows.map((r) => r.dy_m));
  const dz = axis(rows.map((r) => r.dz_m));
  const h = rows.map((r) => Math.hypot(r.dx_m, r.dy_m));
  const d = rows.map(d3Of);
  const d3a = axis(d);
  return {
    n: rows.length, dx, dy, dz,
    horizontal: { rmse: Math.sqrt(h.reduce((a, b) => a + b * b, 0) / h.length), max: Math.max(...h) },
    d3: { mean: d3a.mean, std: d3a.std, rmse: d3a.rmse, max: d3a.maxAbs },
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
export function residualsCsv(rows: ResidualPoint[]): string {
  const st = residualStats(rows);
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
