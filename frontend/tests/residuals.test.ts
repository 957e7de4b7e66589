import { describe, expect, it } from "vitest";
import {
  type ResidualPoint, type ServedStats, DEFAULT_TOLERANCE, classify, d3Of, formatLength, pointClass, residualsCsv, sortResiduals,
  statsFromServed,
} from "../src/lib/residuals";
import served from "./fixtures/residuals_core.json";

const rows: ResidualPoint[] = [
  { name: "T10", role: "check", dx_m: 0.012, dy_m: -0.004, dz_m: 0.021 },
  { name: "T2", role: "check", dx_m: -0.006, dy_m: 0.008, dz_m: -0.035 },
  { name: "T1", role: "check", dx_m: 0.003, dy_m: 0.001, dz_m: 0.007 },
];

describe("residual statistics", () => {
  it("shows the statistics the georef step wrote, not its own (one definition: residual_table.residual_statistics)", () => {
    // residuals.json of a run as the core writes it (frontend/tests/fixtures/residuals_core.json, made and kept
    // equal to the core's output by tests/adjustment/test_residual_statistics.py)
    const s = statsFromServed(served.statistics as ServedStats)!;
    expect(s.n).toBe(served.points.length);
    expect(s.dx.std).toBe(served.statistics.dx.std_m);
    expect(s.dz.rmse).toBe(served.statistics.dz.rmse_m);
    expect(s.d3.std).toBe(served.statistics["3d"].std_m);
    expect(s.horizontal.rmse).toBe(served.statistics.horizontal.rmse_m);
    expect(statsFromServed({ n: 0 })).toBeNull();
    expect(statsFromServed(undefined)).toBeNull();
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

  it("writes CSV with the served statistics rows", () => {
    const s = statsFromServed(served.statistics as ServedStats)!;
    const pts = served.points.map((p) => ({ ...p, dx_m: p.dx_m, dy_m: p.dy_m, dz_m: p.dz_m })) as ResidualPoint[];
    const csv = residualsCsv(pts, s).trim().split("\n");
    expect(csv[0]).toBe("point,role,dx_m,dy_m,dz_m,d3_m");
    expect(csv).toHaveLength(1 + pts.length + 3);
    expect(csv[pts.length + 1]).toBe(["mean", "", s.dx.mean.toFixed(4), s.dy.mean.toFixed(4), s.dz.mean.toFixed(4), s.d3.mean.toFixed(4)].join(","));
    expect(residualsCsv(pts, null).trim().split("\n")).toHaveLength(1 + pts.length);
  });
});
