import { describe, expect, it } from "vitest";
import {
  type ResidualPoint, DEFAULT_TOLERANCE, classify, d3Of, formatLength, pointClass, residualStats, residualsCsv, sortResiduals,
} from "../src/lib/residuals";

const rows: ResidualPoint[] = [
  { name: "T10", role: "check", dx_m: 0.012, dy_m: -0.004, dz_m: 0.021 },
  { name: "T2", role: "check", dx_m: -0.006, dy_m: 0.008, dz_m: -0.035 },
  { name: "T1", role: "check", dx_m: 0.003, dy_m: 0.001, dz_m: 0.007 },
];

describe("residual statistics", () => {
  it("computes mean, sample std (n-1) and RMSE per axis, like georef_core's table", () => {
    const s = residualStats(rows)!;
    expect(s.n).toBe(3);
    expect(s.dx.mean).toBeCloseTo(0.003, 12);
    // sample std of (0.012, -0.006, 0.003): deviations 0.009, -0.009, 0 -> sqrt(0.000162 / 2) = 0.009
    expect(s.dx.std!).toBeCloseTo(0.009, 12);
    expect(s.dz.rmse).toBeCloseTo(Math.sqrt((0.021 ** 2 + 0.035 ** 2 + 0.007 ** 2) / 3), 12);
    expect(s.dz.maxAbs).toBeCloseTo(0.035, 12);
    expect(s.horizontal.rmse).toBeCloseTo(Math.sqrt((0.012 ** 2 + 0.004 ** 2 + 0.006 ** 2 + 0.008 ** 2 + 0.003 ** 2 + 0.001 ** 2) / 3), 12);
    expect(s.d3.max).toBeCloseTo(d3Of(rows[1]), 12);
    expect(residualStats([])).toBeNull();
    expect(residualStats([rows[0]])!.dx.std).toBeNull();
  });

  it("formats lengths in cm/mm/m without negative zero", () => {
    expect(formatLength(0.0123, "cm")).toBe("1.2");
    expect(formatLength(-0.0004, "cm")).toBe("0.0");
    expect(formatLength(0.0123, "mm")).toBe("12");
    expect(formatLength(0.0123, "m")).toBe("0.012");
    expect(formatLength(0.0123, "cm", true)).toBe("+1.2");
    expect(formatLength(null)).toBe("–");
    expect(formatLength(NaN)).toBe("–");
  });

  it("colours against the tolerance: ok, warn (up to 1.5x), bad", () => {
    expect(classify(0.02, 0.03)).toBe("ok");
    expect(classify(-0.04, 0.03)).toBe("warn");
    expect(classify(0.05, 0.03)).toBe("bad");
    expect(pointClass(rows[1], DEFAULT_TOLERANCE)).toBe("ok"); // |h| 1.0 cm, dz 3.5 cm < 5 cm
    expect(pointClass({ name: "x", role: "check", dx_m: 0.05, dy_m: 0, dz_m: 0 }, DEFAULT_TOLERANCE)).toBe("bad");
  });

  it("sorts by absolute value and names naturally", () => {
    expect(sortResiduals(rows, "name", false).map((r) => r.name)).toEqual(["T1", "T2", "T10"]);
    expect(sortResiduals(rows, "dz_m", true).map((r) => r.name)).toEqual(["T2", "T10", "T1"]);
    expect(sortResiduals(rows, "d3_m", false)[0].name).toBe("T1");
  });

  it("writes CSV with the statistics rows", () => {
    const csv = residualsCsv(rows).trim().split("\n");
    expect(csv[0]).toBe("point,role,dx_m,dy_m,dz_m,d3_m");
    expect(csv).toHaveLength(1 + 3 + 3);
    expect(csv[4].startsWith("mean,,0.0030,")).toBe(true);
  });
});
