/** Formatting for people: sizes, durations, dates, volumes. */

export function formatBytes(n: number): string {
  if (!Number.isFinite(n)) return "–";
  const u = ["B", "kB", "MB", "GB", "TB"];
  let i = 0;
  let v = n;
  while (v >= 1000 && i < u.length - 1) {
    v /= 1000;
    i++;
  }
  return `${i === 0 ? v.toFixed(0) : v < 10 ? v.toFixed(1) : v.toFixed(0)} ${u[i]}`;
}

export function formatDuration(s: number | null | undefined): string {
  if (s === null || s === undefined || !Number.isFinite(s) || s < 0) return "–";
  if (s < 1) return "< 1 s";
  if (s < 60) return `${Math.round(s)} s`;
  if (s < 3600) {
    const m = Math.floor(s / 60);
    const r = Math.round(s - m * 60);
    return r ? `${m} min ${r} s` : `${m} min`;
  }
  const h = Math.floor(s / 3600);
  const m = Math.round((s - h * 3600) / 60);
  return `${h} h ${m} min`;
}

/** "2024-06-24 08:10 UTC" (sites are run in UTC; the survey dates are what matters). */
export function formatDateTime(iso: string | null | undefined): string {
  if (!iso) return "–";
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return iso;
  return `${d.toISOString().slice(0, 10)} ${d.toISOString().slice(11, 16)} UTC`;
}

export function formatDate(iso: string | null | undefined): string {
  if (!iso) return "–";
  const d = new Date(iso);
  return Number.isNaN(d.getTime()) ? iso : d.toISOString().slice(0, 10);
}

/**
 * Volumes, one rule everywhere (the PDF report's too: backend/services/display.py, checked against the same
 * cases in tests/fixtures/volume_format_cases.json): as many decimals as the uncertainty supports (its first
 * two significant digits: 15.24 ± 0.13, 1,523 ± 12), at most 3; without an uncertainty, by magnitude
 * (2 decimals below 100 m³, 1 below 10 000, then none). Thousands separated by commas.
 */
export function volumeDecimals(m3: number | null | undefined, sigma?: number | null): number {
  if (typeof sigma === "number" && Number.isFinite(sigma) && sigma > 0) return Math.max(0, Math.min(3, 1 - Math.floor(Math.log10(sigma))));
  const a = typeof m3 === "number" && Number.isFinite(m3) ? Math.abs(m3) : 0;
  return a < 100 ? 2 : a < 10000 ? 1 : 0;
}

function fixedWithCommas(v: number, decimals: number): string {
  return v.toLocaleString("en-GB", { minimumFractionDigits: decimals, maximumFractionDigits: decimals, useGrouping: true });
}

/** "15.24" (no unit), "–" without a value; `sigma` (1σ, m³) sets the decimals. */
export function formatVolumeNumber(m3: number | null | undefined, sigma?: number | null): string {
  if (m3 === null || m3 === undefined || !Number.isFinite(m3)) return "–";
  return fixedWithCommas(m3, volumeDecimals(m3, sigma));
}

/** "15.24 m³"; `sigma` (1σ, m³) sets the decimals (it is not shown: formatVolumePm shows it). */
export function formatVolume(m3: number | null | undefined, sigma?: number | null): string {
  const s = formatVolumeNumber(m3, sigma);
  return s === "–" ? s : `${s} m³`;
}

/** "15.24 ± 0.13 m³" (the uncertainty with the value's decimals), or the value alone. */
export function formatVolumePm(m3: number | null | undefined, sigma?: number | null): string {
  const s = formatVolumeNumber(m3, sigma);
  if (s === "–" || typeof sigma !== "number" || !Number.isFinite(sigma) || !(sigma > 0)) return s === "–" ? s : `${s} m³`;
  return `${s} ± ${fixedWithCommas(sigma, volumeDecimals(m3, sigma))} m³`;
}

const FLIGHT_SOURCE: Record<string, string> = {
  gnss: "from the GNSS data",
  "dji-mrk": "from the DJI MRK file",
  exif: "from the photos' EXIF times",
};

/**
 * When the survey was flown: the date given, or the one a run read from the data (GNSS solution, DJI MRK,
 * EXIF), never the upload date. `text` for a table cell; `note` says where a date read from the data comes from.
 */
export function flightDate(s: { flown_at: string | null; flown_at_source?: string | null }): { text: string; note: string; known: boolean } {
  if (!s.flown_at) return { text: "not known yet", note: "no date given; read from the data when the survey is processed", known: false };
  const src = s.flown_at_source ? FLIGHT_SOURCE[s.flown_at_source] : undefined;
  return { text: formatDate(s.flown_at), note: src ?? "", known: true };
}

export function formatArea(m2: number | null | undefined): string {
  if (m2 === null || m2 === undefined || !Number.isFinite(m2)) return "–";
  return `${m2 >= 100 ? Math.round(m2).toLocaleString("en-GB") : m2.toFixed(1)} m²`;
}

export function formatPercent(x: number): string {
  return `${Math.round(x * 100)} %`;
}
