/**
 * Accuracy: the check-point residual table and its plan, control/check roles (switch and recompute),
 * the PPK quality over time and the estimated lever arm and trigger delay with their sigmas.
 */

import { useState } from "preact/hooks";
import { api } from "../api/client";
import { checkRows, residualRows } from "../api/summaries";
import type { ApiPoint, LeverArm, ResidualsResponse, Run, RunDetail, TrajectoryResponse } from "../api/types";
import { PpkChart } from "../components/PpkChart";
import { qualityFromSummary } from "../lib/ppkQuality";
import { ResidualMap } from "../components/ResidualMap";
import { ResidualTable } from "../components/ResidualTable";
import { ErrorBox, Figure, Loading, Note } from "../components/ui";
import { useLoad, useStored } from "../hooks";
import { DEFAULT_TOLERANCE, type Tolerance, type Unit, formatLength, residualsCsv, statsFromServed } from "../lib/residuals";
import { showRun } from "./startRun";
import type { SurveyContext } from "./surveyContext";

export function AccuracyView({ ctx, run }: { ctx: SurveyContext; run: Run }) {
  const res = useLoad((signal) => api.maybe<ResidualsResponse>(`/runs/${run.id}/results/residuals`, { signal }), [run.id]);
  const points = useLoad((signal) => api.get<ApiPoint[]>(`/surveys/${ctx.survey.id}/points`, { signal }).catch(() => [] as ApiPoint[]), [ctx.survey.id]);
  const lever = useLoad((signal) => api.maybe<LeverArm>(`/runs/${run.id}/results/lever-arm`, { signal }), [run.id]);
  const traj = useLoad((signal) => api.maybe<TrajectoryResponse>(`/runs/${run.id}/results/trajectory`, { query: { format: "json", every: 2 }, signal }), [run.id]);
  // the epoch counts are the GNSS step's (its summary), as in the processing view and the PDF: the chart's
  // trajectory is every 2nd epoch
  const detail = useLoad((signal) => api.maybe<RunDetail>(`/runs/${run.id}`, { signal }), [run.id]);
  const gnssCounts = qualityFromSummary(detail.data?.step_details.find((s) => s.name === "gnss")?.summary);
  // the site's tolerance (set on the site, shared by everyone); a change here is remembered in this browser
  const siteTolerance: Tolerance = {
    horizontal_m: ctx.site.tolerance_horizontal_m ?? DEFAULT_TOLERANCE.horizontal_m,
    vertical_m: ctx.site.tolerance_vertical_m ?? DEFAULT_TOLERANCE.vertical_m,
  };
  const [tol, setTol] = useStored<Tolerance>(`georef.tolerance.${ctx.site.id}`, siteTolerance);
  const [unit, setUnit] = useStored<Unit>("georef.unit", "cm");

  const checks = checkRows(res.data ?? null);
  const all = residualRows(res.data ?? null);
  const checkNames = new Set(checks.map((r) => r.name + "|" + r.role));
  const others = all.filter((r) => !checkNames.has(r.name + "|" + r.role));
  // the statistics the georef step wrote (one definition for the API, the PDF and this view)
  const st = statsFromServed(res.data?.stats);

  const downloadCsv = () => {
    const blob = new Blob([residualsCsv(checks, st)], { type: "text/csv" });
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = `${ctx.survey.name.replace(/[^\w.-]+/g, "_")}_run${run.number}_check_residuals.csv`;
    a.click();
    setTimeout(() => URL.revokeObjectURL(a.href), 1000);
  };

  return (
    <div class="accuracy">
      <div class="settings-row">
        <fieldset class="inline">
          <legend>Site tolerance</legend>
          <label>horizontal <input type="number" min="0.1" step="0.5" value={+(tol.horizontal_m * 100).toFixed(2)} onChange={(e) => setTol({ ...tol, horizontal_m: Math.max(0.001, Number((e.target as HTMLInputElement).value) / 100) })} /> cm</label>
          <label>vertical <input type="number" min="0.1" step="0.5" value={+(tol.vertical_m * 100).toFixed(2)} onChange={(e) => setTol({ ...tol, vertical_m: Math.max(0.001, Number((e.target as HTMLInputElement).value) / 100) })} /> cm</label>
        </fieldset>
        <label>Unit <select value={unit} onChange={(e) => setUnit((e.target as HTMLSelectElement).value as Unit)}>
          <option value="mm">mm</option><option value="cm">cm</option><option value="m">m</option>
        </select></label>
      </div>

      <section aria-labelledby="res-title">
        <h2 id="res-title">Check points</h2>
        <ErrorBox error={res.error} />
        {res.loading && !res.data ? <Loading what="the residuals" /> : null}
        {!res.loading && !res.data ? <Note>This run has no residual table (georeferencing not run, or no ground points).</Note> : null}
        {st ? (
          <div class="figures" aria-label="Summary">
            <Figure label="RMSE horizontal" value={formatLength(st.horizontal.rmse, unit)} unit={unit} />
            <Figure label="RMSE vertical" value={formatLength(st.dz.rmse, unit)} unit={unit} />
            <Figure label="RMSE 3D" value={formatLength(st.d3.rmse, unit)} unit={unit} />
            <Figure label="largest |d|" value={formatLength(st.d3.max, unit)} unit={unit} />
            <Figure label="check points" value={String(st.n)} />
          </div>
        ) : null}
        {checks.length ? (
          <>
            <ResidualTable rows={checks} stats={st} tolerance={tol} unit={unit} caption={`Check-point residuals, run ${run.number}`} />
            <div class="actions">
              <button type="button" class="link" onClick={downloadCsv}>Save this table as CSV</button>
              <a class="link" href={`/api/v1/runs/${run.id}/results/residuals?format=geojson`} download>GeoJSON</a>
            </div>
          </>
        ) : res.data ? <Note kind="warning">No check point in this run: every point was used as control, so the accuracy is not independently verified. Make some points check points below.</Note> : null}
        {others.length ? <ResidualTable rows={others} tolerance={tol} unit={unit} caption="Control points (left out one at a time, or fit)" /> : null}
      </section>

      {checks.length && points.data ? (
        <section aria-labelledby="plan-title">
          <h2 id="plan-title">Residuals on the site</h2>
          <ResidualMap rows={checks} points={points.data} tolerance={tol} />
        </section>
      ) : null}

      {points.data && points.data.length ? <PointRoles ctx={ctx} run={run} points={points.data} onChanged={points.reload} /> : null}

      <div class="two-col">
        <section aria-labelledby="ppk-title">
          <h2 id="ppk-title">GNSS trajectory</h2>
          <ErrorBox error={traj.error} />
          {traj.loading && !traj.data ? <Loading what="the trajectory" /> : null}
          {traj.data ? <PpkChart epochs={traj.data.epochs} counts={gnssCounts} /> : !traj.loading ? <Note>No trajectory in this run.</Note> : null}
        </section>
        <section aria-labelledby="lever-title">
          <h2 id="lever-title">Lever arm and trigger delay</h2>
          <ErrorBox error={lever.error} />
          {lever.data ? <LeverArmCard l={lever.data} /> : !lever.loading ? <Note>Not estimated in this run.</Note> : null}
        </section>
      </div>
    </div>
  );
}

function pm(v: number, s: number | null | undefined, f: number, dec: number): string {
  return `${(v * f).toFixed(dec)}${s !== null && s !== undefined ? ` ± ${(s * f).toFixed(dec)}` : ""}`;
}

function LeverArmCard({ l }: { l: LeverArm }) {
  const s = l.lever_arm_sigma_m;
  return (
    <div class="card">
      <table class="data compact">
        <caption class="sr-only">Lever arm (camera frame) and trigger delay, with one-sigma uncertainties</caption>
        <thead><tr><th scope="col">Quantity</th><th scope="col" class="num">Value ± σ</th><th scope="col">Estimated</th></tr></thead>
        <tbody>
          {["x (right)", "y (down)", "z (forward)"].map((axis, i) => (
            <tr key={axis}>
              <th scope="row">Lever arm {axis}</th>
              <td class="num">{pm(l.lever_arm_cam_m[i], s?.[i], 100, 1)} cm</td>
              <td>{l.estimated?.lever_arm ?? !!s ? "yes" : "fixed"}</td>
            </tr>
          ))}
          <tr>
            <th scope="row">Trigger delay</th>
            <td class="num">{pm(l.delay_s, l.delay_sigma_s, 1000, 1)} ms</td>
            <td>{l.estimated?.delay ?? l.delay_sigma_s !== null ? "yes" : "fixed"}</td>
          </tr>
          {l.readout_s !== undefined && l.readout_s !== null ? (
            <tr>
              <th scope="row">Rolling-shutter readout</th>
              <td class="num">{pm(l.readout_s, l.readout_sigma_s, 1000, 1)} ms</td>
              <td>{l.estimated?.readout ?? (l.readout_sigma_s !== null && l.readout_sigma_s !== undefined) ? "yes" : "fixed"}</td>
            </tr>
          ) : null}
        </tbody>
      </table>
      {l.model ? <p class="small muted">Model: <code>{l.model}</code> (antenna A at the trigger, camera frame axes as in OpenCV).</p> : null}
    </div>
  );
}

function PointRoles({ ctx, run, points, onChanged }: { ctx: SurveyContext; run: Run; points: ApiPoint[]; onChanged: () => void }) {
  const [roles, setRoles] = useState<Record<string, string>>({});
  const [busy, setBusy] = useState(false);
  const [error, setError] = useState<Error | null>(null);
  const changed = points.filter((p) => roles[p.name] && roles[p.name] !== p.role);
  const nCheck = points.filter((p) => (roles[p.name] ?? p.role) === "check").length;
  const nControl = points.length - nCheck;

  const apply = async () => {
    setBusy(true);
    setError(null);
    try {
      for (const p of changed) await api.patch(`/surveys/${ctx.survey.id}/points/${encodeURIComponent(p.name)}`, { role: roles[p.name] });
      onChanged();
      const r = await api.post<RunDetail>(`/runs/${run.id}/rerun`, { from_step: "georef", settings: {} });
      showRun(ctx, r.id);
    } catch (e) {
      setError(e as Error);
    } finally {
      setBusy(false);
    }
  };

  return (
    <section aria-labelledby="roles-title">
      <h2 id="roles-title">Control and check points</h2>
      <p class="small muted">Control points constrain the adjustment; check points only measure its accuracy. Switch roles and recompute from the georeferencing step (the GNSS trajectory is reused).</p>
      <div class="table-wrap">
        <table class="data compact roles">
          <thead><tr><th scope="col">Point</th><th scope="col" class="num">Easting (m)</th><th scope="col" class="num">Northing (m)</th><th scope="col" class="num">Height (m)</th><th scope="col">Role</th></tr></thead>
          <tbody>
            {points.map((p) => {
              const cur = roles[p.name] ?? p.role;
              return (
                <tr key={p.name} class={cur !== p.role ? "changed" : ""}>
                  <th scope="row">{p.name}</th>
                  <td class="num">{p.easting_m.toFixed(3)}</td>
                  <td class="num">{p.northing_m.toFixed(3)}</td>
                  <td class="num">{p.ellipsoidal_height_m.toFixed(3)}</td>
                  <td>
                    <span role="radiogroup" aria-label={`Role of ${p.name}`} class="segmented">
                      {["control", "check"].map((r) => (
                        <label key={r} class={cur === r ? "on" : ""}>
                          <input type="radio" name={`role-${p.name}`} value={r} checked={cur === r} disabled={!ctx.canEdit || busy} onChange={() => setRoles({ ...roles, [p.name]: r })} />
                          {r}
                        </label>
                      ))}
                    </span>
                  </td>
                </tr>
              );
            })}
          </tbody>
        </table>
      </div>
      <p class="small">{nControl} control, {nCheck} check{nControl < 3 ? " — fewer than 3 control points: the adjustment relies on GNSS alone" : ""}.</p>
      <ErrorBox error={error} />
      {ctx.canEdit ? (
        <div class="actions">
          <button type="button" class="primary" disabled={!changed.length || busy} onClick={apply}>
            {busy ? "Recomputing…" : changed.length ? `Apply ${changed.length} change${changed.length > 1 ? "s" : ""} and recompute` : "Recompute"}
          </button>
          {changed.length ? <button type="button" class="ghost" onClick={() => setRoles({})}>Undo</button> : null}
        </div>
      ) : null}
    </section>
  );
}
