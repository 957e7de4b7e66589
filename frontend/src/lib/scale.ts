/** Axis scales and "nice" tick values for the SVG charts. */

export function niceStep(span: number, count: number): number {
  if (!(span > 0) || !(count > 0)) return 1;
  const raw = span / count;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const f = raw / mag;
  const nice = f <= 1 ? 1 : f <= 2 ? 2 : f <= 2.5 ? 2.5 : f <= 5 ? 5 : 10;
  return nice * mag;
}

/** Round tick values covering [min, max] (about `count` of them). */
export function niceTicks(min: number, max: number, count = 5): number[] {
  if (!Number.isFinite(min) || !Number.isFinite(max)) return [];
  if (min === max) {
    const d = Math.abs(min) > 0 ? Math.abs(min) * 0.1 : 1;
    min -= d;
    max += d;
  }
  const step = niceStep(max - min, count);
  const out: number[] = [];
  const start = Math.ceil(min / step - 1e-9) * step;
  for (let v = start; v <= max + step * 1e-9; v += step) out.push(Math.abs(v) < step * 1e-9 ? 0 : +v.toPrecision(12));
  return out;
}

/** Domain padded outward to tick boundaries. */
export function niceDomain(min: number, max: number, count = 5): [number, number] {
  if (min === max) {
    const d = Math.abs(min) > 0 ? Math.abs(min) * 0.1 : 1;
    return [min - d, max + d];
  }
  const step = niceStep(max - min, count);
  return [Math.floor(min / step) * step, Math.ceil(max / step) * step];
}

export function linear(d0: number, d1: number, r0: number, r1: number): (v: number) => number {
  const k = d1 !== d0 ? (r1 - r0) / (d1 - d0) : 0;
  return (v) => r0 + (v - d0) * k;
}

/** Decimal places that tell ticks of this step apart. */
export function decimalsFor(step: number): number {
  if (!(step > 0)) return 0;
  return Math.max(0, Math.min(6, -Math.floor(Math.log10(step) + 1e-9)));
}

/**
 * Tick labels that do not overlap: ticks taken in the order given (the most important first), each kept
 * only when it is at least `minPx` away from every tick already kept; returned in value order.
 */
export function spacedTicks(ticks: number[], toPx: (v: number) => number, minPx = 11): number[] {
  const kept: number[] = [];
  for (const t of ticks) if (kept.every((k) => Math.abs(toPx(k) - toPx(t)) >= minPx)) kept.push(t);
  return kept.sort((a, b) => a - b);
}

/** A tick's label with the decimals that tell the ticks apart (0.2, 0.4 ... not 0, 0 ...). */
export function tickLabel(v: number, ticks: number[]): string {
  const sorted = [...ticks].sort((a, b) => a - b);
  let step = Infinity;
  for (let i = 1; i < sorted.length; i++) if (sorted[i] - sorted[i - 1] > 0) step = Math.min(step, sorted[i] - sorted[i - 1]);
  const tol = (Number.isFinite(step) ? step : Math.abs(v) || 1) * 1e-6;
  let dec = Number.isFinite(step) ? decimalsFor(step) : 0;
  while (dec < 6 && sorted.some((t) => Math.abs(+t.toFixed(dec) - t) > tol)) dec++;   // 2.5-steps need one more
  return v.toFixed(dec);
}
