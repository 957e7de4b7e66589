/**
 * A plain SVG line chart (no chart library): several series on a numeric or time x axis, optional
 * error bars and point markers, accessible as an image with a summary, and as a table on demand.
 */

import { useState } from "preact/hooks";
import { decimalsFor, linear, niceDomain, niceStep, niceTicks } from "../lib/scale";

export interface SeriesPoint {
  x: number;
  y: number | null;
  err?: number | null;
  label?: string;
}

export interface Series {
  name: string;
  colour: string;
  points: SeriesPoint[];
  markers?: boolean;
  dashed?: boolean;
}

export interface LineChartProps {
  series: Series[];
  title: string;
  yLabel: string;
  xLabel?: string;
  xTime?: boolean;
  height?: number;
  yFormat?: (v: number) => string;
  /** how values (and their error bars) are written in the summary, the tooltips and the table; default yFormat */
  valueFormat?: (v: number) => string;
  xFormat?: (v: number) => string;
  yZero?: boolean;
}

const W = 720;

function timeFmt(span: number) {
  return (ms: number) => {
    const d = new Date(ms);
    const iso = d.toISOString();
    return span > 3 * 86400e3 ? iso.slice(0, 10) : span > 3600e3 * 6 ? iso.slice(5, 16).replace("T", " ") : iso.slice(11, 19);
  };
}

export function LineChart(p: LineChartProps) {
  const [asTable, setAsTable] = useState(false);
  const H = p.height ?? 240;
  const m = { l: 64, r: 16, t: 12, b: 40 };
  const all = p.series.flatMap((s) => s.points.filter((q) => q.y !== null && Number.isFinite(q.y)));
  if (!all.length) return <p class="muted">{p.title}: no data yet.</p>;
  let x0 = Math.min(...all.map((q) => q.x)), x1 = Math.max(...all.map((q) => q.x));
  if (x0 === x1) {
    x0 -= p.xTime ? 86400e3 : 1;
    x1 += p.xTime ? 86400e3 : 1;
  }
  let y0 = Math.min(...all.map((q) => (q.y as number) - (q.err ?? 0)));
  let y1 = Math.max(...all.map((q) => (q.y as number) + (q.err ?? 0)));
  if (p.yZero) {
    y0 = Math.min(0, y0);
    y1 = Math.max(0, y1);
  }
  [y0, y1] = niceDomain(y0, y1, 4);
  const sx = linear(x0, x1, m.l, W - m.r);
  const sy = linear(y0, y1, H - m.b, m.t);
  const yTicks = niceTicks(y0, y1, 4);
  const yDec = decimalsFor(niceStep(y1 - y0, 4));
  const fy = p.yFormat ?? ((v: number) => v.toFixed(yDec));
  const fv = p.valueFormat ?? fy;
  const fx = p.xFormat ?? (p.xTime ? timeFmt(x1 - x0) : (v: number) => String(+v.toPrecision(6)));
  const xTicks = p.xTime
    ? Array.from({ length: 5 }, (_, i) => x0 + ((x1 - x0) * i) / 4)
    : niceTicks(x0, x1, 5);
  const summary = p.series
    .map((s) => {
      const ys = s.points.filter((q) => q.y !== null).map((q) => q.y as number);
      return ys.length ? `${s.name}: ${ys.length} values from ${fv(Math.min(...ys))} to ${fv(Math.max(...ys))} ${p.yLabel}` : `${s.name}: no values`;
    })
    .join("; ");
  return (
    <figure class="chart">
      <figcaption>
        <span>{p.title}</span>
        <button type="button" class="link small" onClick={() => setAsTable(!asTable)} aria-pressed={asTable}>
          {asTable ? "Show chart" : "Show as table"}
        </button>
      </figcaption>
      {asTable ? (
        <div class="table-wrap">
          <table class="data">
            <thead>
              <tr>
                <th scope="col">series</th>
                <th scope="col">{p.xLabel ?? (p.xTime ? "time (UTC)" : "x")}</th>
                <th scope="col">{p.yLabel}</th>
              </tr>
            </thead>
            <tbody>
              {p.series.flatMap((s) =>
                s.points.slice(0, 500).map((q, i) => (
                  <tr key={`${s.name}${i}`}>
                    <td>{s.name}</td>
                    <td>{q.label ?? fx(q.x)}</td>
                    <td class="num">{q.y === null ? "–" : fv(q.y)}{q.err ? ` ± ${fv(q.err)}` : ""}</td>
                  </tr>
                )),
              )}
            </tbody>
          </table>
        </div>
      ) : (
        <svg viewBox={`0 0 ${W} ${H}`} role="img" aria-label={`${p.title}. ${summary}`} class="chart-svg" preserveAspectRatio="xMidYMid meet">
          {yTicks.map((t) => (
            <g key={`y${t}`}>
              <line x1={m.l} x2={W - m.r} y1={sy(t)} y2={sy(t)} class="grid" />
              <text x={m.l - 6} y={sy(t) + 4} class="tick" text-anchor="end">{fy(t)}</text>
            </g>
          ))}
          {xTicks.map((t, i) => (
            <text key={`x${i}`} x={sx(t)} y={H - m.b + 16} class="tick" text-anchor={i === 0 ? "start" : i === xTicks.length - 1 ? "end" : "middle"}>{fx(t)}</text>
          ))}
          <text x={14} y={(H - m.b + m.t) / 2} class="axis-label" transform={`rotate(-90 14 ${(H - m.b + m.t) / 2})`} text-anchor="middle">{p.yLabel}</text>
          {p.xLabel ? <text x={(W + m.l) / 2} y={H - 4} class="axis-label" text-anchor="middle">{p.xLabel}</text> : null}
          {p.series.map((s) => {
            const pts = s.points.filter((q) => q.y !== null && Number.isFinite(q.y));
            // break the line where values are missing
            const segs: SeriesPoint[][] = [];
            let cur: SeriesPoint[] = [];
            for (const q of s.points) {
              if (q.y === null || !Number.isFinite(q.y)) {
                if (cur.length) segs.push(cur);
                cur = [];
              } else cur.push(q);
            }
            if (cur.length) segs.push(cur);
            return (
              <g key={s.name}>
                {segs.map((seg, k) => (
                  <polyline key={k} fill="none" stroke={s.colour} stroke-width={2} stroke-dasharray={s.dashed ? "6 4" : undefined}
                    points={seg.map((q) => `${sx(q.x).toFixed(1)},${sy(q.y as number).toFixed(1)}`).join(" ")} />
                ))}
                {pts.map((q, i) =>
                  q.err ? (
                    <line key={`e${i}`} x1={sx(q.x)} x2={sx(q.x)} y1={sy((q.y as number) - q.err)} y2={sy((q.y as number) + q.err)} stroke={s.colour} stroke-width={1.5} />
                  ) : null,
                )}
                {s.markers || pts.length <= 40
                  ? pts.map((q, i) => (
                    <circle key={`m${i}`} cx={sx(q.x)} cy={sy(q.y as number)} r={3.5} fill={s.colour}>
                      <title>{`${q.label ?? fx(q.x)}: ${fv(q.y as number)} ${p.yLabel}${q.err ? ` ± ${fv(q.err)}` : ""}`}</title>
                    </circle>
                  ))
                  : null}
              </g>
            );
          })}
        </svg>
      )}
      {p.series.length > 1 ? (
        <ul class="legend">
          {p.series.map((s) => (
            <li key={s.name}>
              <span class="swatch" style={{ background: s.colour }} aria-hidden="true" /> {s.name}
            </li>
          ))}
        </ul>
      ) : null}
    </figure>
  );
}
