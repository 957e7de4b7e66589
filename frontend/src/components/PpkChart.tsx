/** PPK quality over the flight (SVG): fix/float band, satellites, AR ratio, vertical sigma. */

import { type Epoch, type QualityCounts, Q_NAME, bucketEpochs, qualityShares } from "../lib/ppkQuality";
import { linear, niceTicks, spacedTicks, tickLabel } from "../lib/scale";

const W = 720, L = 64, R = 12;
const QCOL: Record<number, string> = { 1: "var(--ok)", 2: "var(--warn)" };

/**
 * `epochs`: the trajectory as fetched (possibly every n-th epoch: it is only drawn); `counts`: the GNSS
 * step's own epoch counts (qualityFromSummary), the figures the caption states, as the processing view and
 * the PDF do. Without them the caption counts what was fetched.
 */
export function PpkChart({ epochs, counts }: { epochs: Epoch[]; counts?: QualityCounts | null }) {
  if (!epochs.length) return <p class="muted">No trajectory epochs.</p>;
  const buckets = bucketEpochs(epochs, 600);
  const t0 = epochs[0].gps_time_s, t1 = epochs[epochs.length - 1].gps_time_s;
  const sx = linear(t0, t1 > t0 ? t1 : t0 + 1, L, W - R);
  const shares = counts
    ? { fix: counts.fix / counts.epochs, float: counts.float / counts.epochs, other: counts.other / counts.epochs }
    : qualityShares(epochs);
  const nEpochs = counts ? counts.epochs : epochs.length;
  const maxNs = Math.max(...buckets.map((b) => (Number.isFinite(b.minNs) ? b.minNs : 0)), 4);
  const ratioCap = 50;
  const sdus = buckets.map((b) => b.maxSdu).filter((v): v is number => v !== null);
  const maxSdu = sdus.length ? Math.min(Math.max(...sdus), 1) : 0;
  // sigma up in mm below 10 cm (a fixed solution's 4 mm is not "0 ... 0" cm), else in cm
  const [sduUnit, sduF] = maxSdu < 0.1 ? ["mm", 1000] : ["cm", 100];
  const panels: { title: string; h: number; draw: (y0: number, h: number) => any }[] = [
    {
      title: "Solution", h: 26,
      draw: (y0, h) => buckets.map((b, i) => (
        <rect key={i} x={sx(b.t0)} y={y0} width={Math.max(1, sx(b.t1) - sx(b.t0) + 0.5)} height={h} fill={QCOL[b.worstQ] ?? "var(--bad)"} />
      )),
    },
    { title: "Satellites", h: 70, draw: (y0, h) => lineOf(buckets.map((b) => [b.t0, Number.isFinite(b.minNs) ? b.minNs : null]), sx, 0, maxNs, y0, h, "var(--accent)", [0, maxNs]) },
    {
      title: "AR ratio", h: 70,
      draw: (y0, h) => (
        <>
          <line x1={L} x2={W - R} y1={y0 + h - (3 / ratioCap) * h} y2={y0 + h - (3 / ratioCap) * h} class="threshold" />
          {/* the threshold is named at the line's left end, away from the axis labels on the right */}
          <text x={L + 3} y={y0 + h - (3 / ratioCap) * h - 3} class="tick small-tick threshold-label">ratio 3</text>
          {lineOf(buckets.map((b) => [b.t0, b.minRatio === null ? null : Math.min(ratioCap, b.minRatio)]), sx, 0, ratioCap, y0, h, "var(--accent-2)", [0, ratioCap / 2, ratioCap])}
        </>
      ),
    },
  ];
  if (maxSdu > 0) panels.push({ title: `σ up (${sduUnit})`, h: 60, draw: (y0, h) => lineOf(buckets.map((b) => [b.t0, b.maxSdu === null ? null : Math.min(maxSdu, b.maxSdu) * sduF]), sx, 0, maxSdu * sduF, y0, h, "var(--muted-ink)", niceTicks(0, maxSdu * sduF, 2)) });
  const gap = 18;
  const H = panels.reduce((a, p) => a + p.h + gap, 0) + 24;
  let y = 8;
  const dur = t1 - t0;
  const timeTicks = [0, 0.25, 0.5, 0.75, 1].map((f) => t0 + f * dur);
  const label = `PPK quality: ${Math.round(shares.fix * 100)} % fixed, ${Math.round(shares.float * 100)} % float, ${Math.round(shares.other * 100)} % other over ${Math.round(dur / 60)} minutes`;
  return (
    <figure class="chart">
      <figcaption><span>PPK quality over the flight</span><span class="small muted">{Math.round(shares.fix * 100)} % fix · {Math.round(shares.float * 100)} % float · {Math.round(shares.other * 100)} % single/other · {nEpochs} epochs</span></figcaption>
      <svg viewBox={`0 0 ${W} ${H}`} class="chart-svg" role="img" aria-label={label}>
        {panels.map((p) => {
          const y0 = y;
          y += p.h + gap;
          return (
            <g key={p.title}>
              <text x={L - 6} y={y0 + p.h / 2 + 4} class="tick" text-anchor="end">{p.title}</text>
              <rect x={L} y={y0} width={W - R - L} height={p.h} class="panel-bg" />
              {p.draw(y0, p.h)}
            </g>
          );
        })}
        {timeTicks.map((t, i) => (
          <text key={i} x={sx(t)} y={H - 6} class="tick" text-anchor={i === 0 ? "start" : i === 4 ? "end" : "middle"}>{gpsClock(t)}</text>
        ))}
      </svg>
      <ul class="legend">
        <li><span class="swatch" style={{ background: "var(--ok)" }} aria-hidden="true" /> {Q_NAME[1]}</li>
        <li><span class="swatch" style={{ background: "var(--warn)" }} aria-hidden="true" /> {Q_NAME[2]}</li>
        <li><span class="swatch" style={{ background: "var(--bad)" }} aria-hidden="true" /> single / other</li>
        <li>dashed line: ratio 3 (fix threshold); time is GPS time</li>
      </ul>
    </figure>
  );
}

function gpsClock(gpsS: number): string {
  const ms = Date.UTC(1980, 0, 6) + gpsS * 1000;
  return new Date(ms).toISOString().slice(11, 19);
}

function lineOf(pts: [number, number | null][], sx: (v: number) => number, v0: number, v1: number, y0: number, h: number, colour: string, ticks: number[]) {
  const sy = (v: number) => y0 + h - ((v - v0) / (v1 - v0 || 1)) * h;
  // labels at least a line apart (the top one is drawn below its tick, the others above), the range's ends first
  const labelY = (t: number) => sy(t) + (t === v1 ? 10 : -2);
  const shown = spacedTicks([...ticks.filter((t) => t === v0 || t === v1), ...ticks.filter((t) => t !== v0 && t !== v1)], labelY, 11);
  const segs: string[] = [];
  let cur: string[] = [];
  for (const [t, v] of pts) {
    if (v === null) {
      if (cur.length) segs.push(cur.join(" "));
      cur = [];
    } else cur.push(`${sx(t).toFixed(1)},${sy(v).toFixed(1)}`);
  }
  if (cur.length) segs.push(cur.join(" "));
  return (
    <>
      {shown.map((t) => (
        <text key={t} x={W - R - 2} y={labelY(t)} class="tick small-tick" text-anchor="end">{tickLabel(t, ticks)}</text>
      ))}
      {segs.map((s, i) => <polyline key={i} points={s} fill="none" stroke={colour} stroke-width={1.5} />)}
    </>
  );
}
