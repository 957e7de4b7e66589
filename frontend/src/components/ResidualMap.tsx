/** Residual vectors on a plan (SVG): horizontal residual as an exaggerated arrow, vertical as a bar. */

import { useState } from "preact/hooks";
import type { ApiPoint } from "../api/types";
import { type ResidualPoint, type Tolerance, formatLength, pointClass } from "../lib/residuals";
import { niceStep } from "../lib/scale";

const W = 640, H = 420, PAD = 48;

export function ResidualMap({ rows, points, tolerance }: { rows: ResidualPoint[]; points: ApiPoint[]; tolerance: Tolerance }) {
  const pos = new Map(points.map((p) => [p.name, p]));
  const placed = rows.filter((r) => pos.has(r.name));
  const controls = points.filter((p) => !rows.some((r) => r.name === p.name));
  const all = [...placed.map((r) => pos.get(r.name)!), ...controls];
  const [exag, setExag] = useState<number | null>(null);
  if (!all.length) return <p class="muted">The point coordinates are not available (no points file in the survey).</p>;
  const xs = all.map((p) => p.easting_m), ys = all.map((p) => p.northing_m);
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const span = Math.max(x1 - x0, y1 - y0, 1);
  const k = Math.min((W - 2 * PAD) / Math.max(x1 - x0, span * 0.2), (H - 2 * PAD) / Math.max(y1 - y0, span * 0.2));
  const cx = (W - k * (x1 - x0)) / 2, cy = (H - k * (y1 - y0)) / 2;
  const px = (e: number) => cx + (e - x0) * k;
  const py = (n: number) => H - (cy + (n - y0) * k);
  // Exaggeration: the largest horizontal residual drawn about 60 px long.
  const maxH = Math.max(1e-6, ...placed.map((r) => Math.hypot(r.dx_m, r.dy_m)));
  const auto = niceStep((60 / k / maxH) * 2, 2);
  const ex = exag ?? auto;
  const maxV = Math.max(1e-6, ...placed.map((r) => Math.abs(r.dz_m)));
  const vScale = 40 / maxV; // px per metre for the vertical bars
  const refLen = niceStep(maxH, 2); // length of the scale arrow (m)
  const mapScale = niceStep(span / 4, 1);
  return (
    <figure class="chart">
      <figcaption>
        <span>Residual vectors (arrows × {Math.round(ex).toLocaleString("en-GB")}, bars: height residual)</span>
        <label class="small">Exaggeration{" "}
          <select value={String(ex)} onChange={(e) => setExag(Number((e.target as HTMLSelectElement).value))}>
            {[...new Set([auto, 100, 200, 500, 1000, 2000, 5000])].sort((a, b) => a - b).map((v) => <option key={v} value={String(v)}>× {Math.round(v)}</option>)}
          </select>
        </label>
      </figcaption>
      <svg viewBox={`0 0 ${W} ${H}`} class="chart-svg plan" role="img" aria-label={`Plan of ${placed.length} check points with their residual vectors and ${controls.length} other points`}>
        <defs>
          <marker id="arrow" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="6" markerHeight="6" orient="auto-start-reverse">
            <path d="M0,0 L10,5 L0,10 z" fill="context-stroke" />
          </marker>
        </defs>
        {controls.map((p) => (
          <g key={`c${p.name}`}>
            <path d={`M${px(p.easting_m)},${py(p.northing_m) - 7} l6,11 h-12 z`} class="control-mark" />
            <text x={px(p.easting_m) + 8} y={py(p.northing_m) + 4} class="tick">{p.name}</text>
          </g>
        ))}
        {placed.map((r) => {
          const p = pos.get(r.name)!;
          const x = px(p.easting_m), y = py(p.northing_m);
          const c = pointClass(r, tolerance);
          const dzpx = r.dz_m * vScale;
          return (
            <g key={r.name} class={`vec vec-${c}`}>
              <title>{`${r.name}: dE ${formatLength(r.dx_m, "cm", true)} cm, dN ${formatLength(r.dy_m, "cm", true)} cm, dh ${formatLength(r.dz_m, "cm", true)} cm`}</title>
              <rect x={x + 10} y={dzpx > 0 ? y - dzpx : y} width={5} height={Math.max(1, Math.abs(dzpx))} class="vbar" />
              <circle cx={x} cy={y} r={4} />
              <line x1={x} y1={y} x2={x + r.dx_m * ex * k} y2={y - r.dy_m * ex * k} marker-end="url(#arrow)" />
              <text x={x - 6} y={y - 8} class="tick" text-anchor="end">{r.name}</text>
            </g>
          );
        })}
        <g class="scale" transform={`translate(${PAD / 2}, ${H - 20})`}>
          <line x1={0} y1={0} x2={refLen * ex * k} y2={0} marker-end="url(#arrow)" class="ref-arrow" />
          <text x={0} y={-6} class="tick">{formatLength(refLen, "cm")} cm residual</text>
        </g>
        <g class="scale" transform={`translate(${W - PAD / 2 - mapScale * k}, ${H - 20})`}>
          <line x1={0} y1={0} x2={mapScale * k} y2={0} class="scalebar" />
          <text x={mapScale * k} y={-6} class="tick" text-anchor="end">{mapScale} m</text>
        </g>
        <text x={W - 16} y={24} class="tick" text-anchor="middle">N</text>
        <path d={`M${W - 16},30 l-5,12 h10 z`} class="north" />
      </svg>
      <ul class="legend">
        <li><span class="swatch tol-ok-bg" aria-hidden="true" /> within tolerance</li>
        <li><span class="swatch tol-warn-bg" aria-hidden="true" /> up to 1.5 ×</li>
        <li><span class="swatch tol-bad-bg" aria-hidden="true" /> beyond</li>
        <li><span class="triangle" aria-hidden="true">▲</span> control point</li>
      </ul>
    </figure>
  );
}
