/** The site calibration the datum step applied: its parameters and a table point / dE / dN / dH (mm). */

import { calibrationParameterLines, formatResidualMm, type CalibrationSummary } from "../lib/calibration";

export function CalibrationTable({ c }: { c: CalibrationSummary }) {
  return (
    <div class="calibration" data-testid="site-calibration">
      <div class="small">
        Site calibration{c.name ? ` “${c.name}”` : ""}{c.source ? <span class="muted"> ({c.source})</span> : null}
      </div>
      <ul class="small plain">{calibrationParameterLines(c).map((l) => <li key={l}>{l}</li>)}</ul>
      <div class="table-wrap">
        <table class="data compact">
          <caption class="sr-only">Site calibration residuals per control point: given local minus calibrated, millimetres</caption>
          <thead>
            <tr>
              <th scope="col">Point</th>
              <th scope="col">Use</th>
              <th scope="col" class="num">dE (mm)</th>
              <th scope="col" class="num">dN (mm)</th>
              <th scope="col" class="num">dH (mm)</th>
            </tr>
          </thead>
          <tbody>
            {c.residuals.map((r) => (
              <tr key={r.name}>
                <th scope="row">{r.name}</th>
                <td>{r.use}</td>
                <td class="num">{formatResidualMm(r.dE_m)}</td>
                <td class="num">{formatResidualMm(r.dN_m)}</td>
                <td class="num">{formatResidualMm(r.dH_m)}</td>
              </tr>
            ))}
          </tbody>
        </table>
      </div>
    </div>
  );
}
