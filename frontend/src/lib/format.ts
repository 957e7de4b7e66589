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

/** Volumes: m³ with thousands separators; small volumes keep one decimal. */
export function formatVolume(m3: number | null | undefined): string {
  if (m3 === null || m3 === undefined || !Number.isFinite(m3)) return "–";
  const a = Math.abs(m3);
  const s = a >= 100 ? Math.round(m3).toLocaleString("en-GB") : m3.toFixed(a >= 10 ? 1 : 2);
  return `${s} m³`;
}

export function formatArea(m2: number | null | undefined): string {
  if (m2 === null || m2 === undefined || !Number.isFinite(m2)) return "–";
  return `${m2 >= 100 ? Math.round(m2).toLocaleString("en-GB") : m2.toFixed(1)} m²`;
}

export function formatPercent(x: number): string {
  return `${Math.round(x * 100)} %`;
}
