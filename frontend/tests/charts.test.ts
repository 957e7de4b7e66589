import { describe, expect, it } from "vitest";
import { bucketEpochs, qualityShares } from "../src/lib/ppkQuality";
import { decimalsFor, niceDomain, niceTicks } from "../src/lib/scale";

describe("chart scales", () => {
  it("makes round ticks covering the range", () => {
    expect(niceTicks(0, 10, 5)).toEqual([0, 2, 4, 6, 8, 10]);
    expect(niceTicks(0.013, 0.087, 4)).toEqual([0.02, 0.04, 0.06, 0.08]);
    expect(niceDomain(3, 97, 4)).toEqual([0, 100]);
    expect(decimalsFor(0.25)).toBe(1);
    expect(decimalsFor(0.02)).toBe(2);
    expect(niceTicks(5, 5).length).toBeGreaterThan(1);
  });
});

describe("PPK quality buckets", () => {
  const ep = (t: number, q: number, ns: number, ratio: number | null = 10) => ({ gps_time_s: t, q, ns, ratio, sdu_m: 0.01 });
  it("keeps the worst quality, fewest satellites and lowest ratio of each bucket", () => {
    const epochs = [ep(0, 1, 20), ep(1, 2, 12, 1.5), ep(2, 1, 18), ep(3, 1, 19), ep(4, 5, 6, null), ep(5, 1, 20)];
    const b = bucketEpochs(epochs, 3);
    expect(b).toHaveLength(3);
    expect(b[0].worstQ).toBe(2);
    expect(b[0].minNs).toBe(12);
    expect(b[0].minRatio).toBe(1.5);
    expect(b[2].worstQ).toBe(5);
    expect(b[2].minNs).toBe(6);
    const sh = qualityShares(epochs);
    expect(sh.fix).toBeCloseTo(4 / 6, 12);
    expect(sh.float).toBeCloseTo(1 / 6, 12);
    expect(sh.other).toBeCloseTo(1 / 6, 12);
  });
});
