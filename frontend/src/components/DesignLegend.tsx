import { DESIGN_CLASSES } from "../lib/designClasses";
import { formatVolumePm } from "../lib/format";

/** The cut/fill classes' colours and the run's cut, fill, net (+- 1 sigma) and on-grade share to the design. */
export function DesignLegend({ summary }: { summary: Record<string, any> }) {
  const s = summary.sigma_m3 ?? {};
  const tol = typeof summary.tolerance_m === "number" ? `±${(summary.tolerance_m * 100).toFixed(0)} cm` : "tolerance";
  const share = typeof summary.on_grade_share === "number" ? `${(summary.on_grade_share * 100).toFixed(1)} %` : "–";
  return (
    <div class="design-legend">
      <span class="small">Cut/fill to design{summary.design ? ` (${summary.design})` : ""}</span>
      <ul class="legend" aria-label="Cut/fill classes">
        {DESIGN_CLASSES.filter((c) => c.key !== "no_data").map((c) => (
          <li key={c.key}><span class="swatch" style={{ background: `rgb(${c.rgb.join(",")})` }} /> {c.label}</li>
        ))}
      </ul>
      <p class="small">
        Cut {formatVolumePm(summary.cut_m3, s.cut_m3)}, fill {formatVolumePm(summary.fill_m3, s.fill_m3)}, net{" "}
        {formatVolumePm(summary.net_m3, s.net_m3)} (1σ); on grade ({tol}): {share} of the area.
      </p>
    </div>
  );
}
