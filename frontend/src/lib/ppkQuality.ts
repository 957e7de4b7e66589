/**
 * PPK quality over time from trajectory epochs (RTKLIB Q: 1 fix, 2 float, 3 SBAS, 4 DGPS, 5 single,
 * 6 PPP): per time bucket the worst quality, the fewest satellites and the lowest AR ratio (problems
 * must stay visible when 20 000 epochs become 600 pixels), and the share of each quality.
 */

export interface Epoch {
  gps_time_s: number;
  q: number;
  ns: number;
  ratio: number | null;
  sdu_m: number | null;
}

export interface Bucket {
  t0: number;
  t1: number;
  worstQ: number;
  minNs: number;
  minRatio: number | null;
  maxSdu: number | null;
}

export function bucketEpochs(epochs: Epoch[], n: number): Bucket[] {
  if (!epochs.length) return [];
  const t0 = epochs[0].gps_time_s, t1 = epochs[epochs.length - 1].gps_time_s;
  const span = Math.max(t1 - t0, 1e-6);
  const count = Math.max(1, Math.min(n, epochs.length));
  const out: Bucket[] = [];
  for (let i = 0; i < count; i++) out.push({ t0: t0 + (span * i) / count, t1: t0 + (span * (i + 1)) / count, worstQ: 0, minNs: Infinity, minRatio: null, maxSdu: null });
  for (const e of epochs) {
    const b = out[Math.min(count - 1, Math.floor(((e.gps_time_s - t0) / span) * count))];
    b.worstQ = Math.max(b.worstQ, e.q);
    b.minNs = Math.min(b.minNs, e.ns);
    if (e.ratio !== null && Number.isFinite(e.ratio)) b.minRatio = b.minRatio === null ? e.ratio : Math.min(b.minRatio, e.ratio);
    if (e.sdu_m !== null && Number.isFinite(e.sdu_m)) b.maxSdu = b.maxSdu === null ? e.sdu_m : Math.max(b.maxSdu, e.sdu_m);
  }
  return out.filter((b) => b.worstQ > 0);
}

export function qualityShares(epochs: Epoch[]): { fix: number; float: number; other: number } {
  if (!epochs.length) return { fix: 0, float: 0, other: 0 };
  let fix = 0, flt = 0;
  for (const e of epochs) {
    if (e.q === 1) fix++;
    else if (e.q === 2) flt++;
  }
  return { fix: fix / epochs.length, float: flt / epochs.length, other: 1 - (fix + flt) / epochs.length };
}

export const Q_NAME: Record<number, string> = { 1: "fix", 2: "float", 3: "SBAS", 4: "DGPS", 5: "single", 6: "PPP" };

export interface QualityCounts {
  epochs: number;
  fix: number;
  float: number;
  other: number;
}

/**
 * The solution's epoch counts as the GNSS step counted them (its summary: `epochs`, `fix`, `float`): the
 * one source of these figures for the processing view, the accuracy view and the PDF report (the chart
 * draws a decimated trajectory, whose length is not the number of epochs). Null without a summary.
 */
export function qualityFromSummary(summary: Record<string, any> | null | undefined): QualityCounts | null {
  const n = summary?.epochs;
  if (typeof n !== "number" || !(n > 0)) return null;
  const fix = typeof summary?.fix === "number" ? summary.fix : 0;
  const flt = typeof summary?.float === "number" ? summary.float : 0;
  return { epochs: n, fix, float: flt, other: Math.max(0, n - fix - flt) };
}
