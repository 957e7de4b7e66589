import { RAMPS, rampColour } from "../lib/raster";

/** A horizontal colour bar with its end values. */
export function ColourLegend({ ramp, min, max, unit, label }: { ramp: keyof typeof RAMPS; min: number; max: number; unit: string; label: string }) {
  const stops = Array.from({ length: 11 }, (_, i) => {
    const [r, g, b] = rampColour(i / 10, RAMPS[ramp]);
    return `rgb(${r},${g},${b}) ${i * 10}%`;
  }).join(", ");
  const mid = (min + max) / 2;
  const dec = Math.abs(max - min) < 5 ? 2 : 1;
  return (
    <div class="colour-legend" role="img" aria-label={`${label}: from ${min.toFixed(dec)} to ${max.toFixed(dec)} ${unit}`}>
      <span class="small">{label}</span>
      <div class="colour-bar" style={{ background: `linear-gradient(to right, ${stops})` }} />
      <div class="colour-ticks small"><span>{min.toFixed(dec)}</span><span>{mid.toFixed(dec)}</span><span>{max.toFixed(dec)} {unit}</span></div>
    </div>
  );
}
