/**
 * Time left of a step from its progress samples: the rate over a sliding window (recent speed matters
 * more than the slow start), blended with a prior from earlier runs of the same step when known.
 */

export interface Sample {
  tMs: number;
  done: number;
}

export class EtaEstimator {
  private samples: Sample[] = [];

  constructor(private windowMs = 30000) {}

  add(tMs: number, done: number): void {
    const last = this.samples[this.samples.length - 1];
    if (last && done < last.done) this.samples = []; // a new stage restarted the counter
    this.samples.push({ tMs, done });
    const cutoff = tMs - this.windowMs;
    while (this.samples.length > 2 && this.samples[1].tMs < cutoff) this.samples.shift();
  }

  /** Seconds left to reach `total`, or null when the rate is not known yet. */
  secondsLeft(total: number, priorTotalS?: number | null, elapsedS?: number | null): number | null {
    const n = this.samples.length;
    let fromRate: number | null = null;
    if (n >= 2) {
      const a = this.samples[0], b = this.samples[n - 1];
      const rate = (b.done - a.done) / ((b.tMs - a.tMs) / 1000);
      if (rate > 0) fromRate = Math.max(0, (total - b.done) / rate);
    }
    const fromPrior = priorTotalS != null && elapsedS != null ? Math.max(0, priorTotalS - elapsedS) : null;
    if (fromRate === null) return fromPrior;
    if (fromPrior === null) return fromRate;
    // Trust the measured rate more as the step goes on.
    const frac = total > 0 ? Math.min(1, this.samples[n - 1].done / total) : 0;
    return frac * fromRate + (1 - frac) * fromPrior;
  }
}
