/** The check-point residual table: sortable, coloured against the tolerance, the statistics the georef step
 * wrote below (the browser does not compute its own). */

import { useState } from "preact/hooks";
import {
  type ResidualPoint, type SortKey, type Tolerance, type Unit, type ResidualStats, classify, d3Of, formatLength, pointClass, sortResiduals,
} from "../lib/residuals";

const COLS: [SortKey, string][] = [
  ["name", "Point"],
  ["role", "Role"],
  ["dx_m", "dE"],
  ["dy_m", "dN"],
  ["dz_m", "dh"],
  ["d3_m", "|d|"],
  ["n_images", "Photos"],
];

const CLASS_WORD = { ok: "within tolerance", warn: "up to 1.5 × tolerance", bad: "beyond tolerance" };

export function ResidualTable({ rows, stats, tolerance, unit, caption }: { rows: ResidualPoint[]; stats?: ResidualStats | null; tolerance: Tolerance; unit: Unit; caption: string }) {
  const [sort, setSort] = useState<{ key: SortKey; desc: boolean }>({ key: "name", desc: false });
  const sorted = sortResiduals(rows, sort.key, sort.desc);
  const st = stats ?? null;
  const hasImages = rows.some((r) => r.n_images !== undefined);
  const cols = COLS.filter(([k]) => k !== "n_images" || hasImages);
  const cell = (v: number, tol: number, signed = true) => {
    const c = classify(v, tol);
    return (
      <td class={`num tol-${c}`} title={CLASS_WORD[c]}>
        {formatLength(v, unit, signed)}
      </td>
    );
  };
  const by = (k: SortKey) => setSort((s) => ({ key: k, desc: s.key === k ? !s.desc : k !== "name" && k !== "role" }));
  return (
    <div class="table-wrap">
      <table class="data residuals" data-testid="residual-table">
        <caption>{caption} <span class="muted small">(d = estimated − surveyed, {unit}; colours against ±{formatLength(tolerance.horizontal_m, unit)} {unit} horizontal, ±{formatLength(tolerance.vertical_m, unit)} {unit} vertical)</span></caption>
        <thead>
          <tr>
            {cols.map(([k, label]) => (
              <th key={k} scope="col" class={k === "name" || k === "role" ? "" : "num"} aria-sort={sort.key === k ? (sort.desc ? "descending" : "ascending") : "none"}>
                <button type="button" class="sort" onClick={() => by(k)}>
                  {label}
                  {k !== "name" && k !== "role" && k !== "n_images" ? ` (${unit})` : ""}
                  <span aria-hidden="true" class="sort-mark">{sort.key === k ? (sort.desc ? "▼" : "▲") : ""}</span>
                </button>
              </th>
            ))}
          </tr>
        </thead>
        <tbody>
          {sorted.map((r) => {
            const pc = pointClass(r, tolerance);
            return (
              <tr key={r.name} class={`row-${pc}`} data-point={r.name}>
                <th scope="row">
                  <span class={`dot dot-${pc}`} aria-hidden="true" />
                  {r.name}
                  <span class="sr-only"> ({CLASS_WORD[pc]})</span>
                </th>
                <td>{r.role}</td>
                {cell(r.dx_m, tolerance.horizontal_m)}
                {cell(r.dy_m, tolerance.horizontal_m)}
                {cell(r.dz_m, tolerance.vertical_m)}
                <td class="num" data-col="d3">{formatLength(r.d3_m ?? d3Of(r), unit)}</td>
                {hasImages ? <td class="num">{r.n_images ?? "–"}</td> : null}
              </tr>
            );
          })}
        </tbody>
        {st ? (
          <tfoot>
            {(["mean", "std", "rmse"] as const).map((k) => (
              <tr key={k} data-stat={k}>
                <th scope="row">{k === "rmse" ? "RMSE" : k === "std" ? "std" : "mean"}</th>
                <td class="muted small">n = {st.n}</td>
                {(["dx", "dy", "dz"] as const).map((a) => {
                  const v = k === "mean" ? st[a].mean : k === "std" ? st[a].std : st[a].rmse;
                  const tol = a === "dz" ? tolerance.vertical_m : tolerance.horizontal_m;
                  return k === "rmse" && v !== null ? cell(v, tol, false) : <td key={a} class="num">{formatLength(v, unit, k === "mean")}</td>;
                })}
                <td class="num">{formatLength(k === "mean" ? st.d3.mean : k === "std" ? st.d3.std : st.d3.rmse, unit)}</td>
                {hasImages ? <td /> : null}
              </tr>
            ))}
          </tfoot>
        ) : null}
      </table>
    </div>
  );
}
