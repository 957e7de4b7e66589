import { describe, expect, it } from "vitest";
import { EtaEstimator } from "../src/lib/eta";
import { formatBytes, formatDuration, formatVolume } from "../src/lib/format";
import { parseGcpList, parsePointsCsv } from "../src/lib/tables";

describe("time estimates", () => {
  it("extrapolates the recent rate and blends in the prior", () => {
    const e = new EtaEstimator(30000);
    expect(e.secondsLeft(100)).toBeNull();
    e.add(0, 0);
    e.add(10000, 20);
    expect(e.secondsLeft(100)).toBeCloseTo(40, 6);
    expect(e.secondsLeft(100, 100, 10)).toBeCloseTo(0.2 * 40 + 0.8 * 90, 6);
    e.add(11000, 5); // the counter restarted (new stage)
    expect(e.secondsLeft(100)).toBeNull();
  });
});

describe("formatting", () => {
  it("formats sizes, durations and volumes", () => {
    expect(formatBytes(999)).toBe("999 B");
    expect(formatBytes(1_500_000)).toBe("1.5 MB");
    expect(formatDuration(75)).toBe("1 min 15 s");
    expect(formatDuration(3700)).toBe("1 h 2 min");
    expect(formatVolume(12345.6)).toBe("12,346 m³");
    expect(formatVolume(1.234)).toBe("1.23 m³");
  });
});

describe("tables", () => {
  it("reads points with semicolons, no header, and names each bad row", () => {
    const t = parsePointsCsv("A;1;2;3\nB;4;x;6\nC;7;8;9;check\nA;1;1;1\n");
    expect(t.points.map((p) => p.name)).toEqual(["A", "C"]);
    expect(t.points[1].role).toBe("check");
    expect(t.errors).toEqual(["line 2 (B): easting, northing and height must be numbers", "line 4: point A appears twice"]);
    expect(parsePointsCsv("name,x,y,z,role\nP1,1,2,3,gcp\nP2,1,2,3,banana\n").errors[0]).toMatch(/banana/);
  });

  it("reads ODM gcp_list rows and reports bad lines", () => {
    const g = parseGcpList("EPSG:32653\n1 2 3 10 20 a.jpg T1\n1 2 3 10 20 b.jpg T1\n1 2 x 10 20 c.jpg\n");
    expect(g.measurements).toBe(2);
    expect(g.images).toEqual(["a.jpg", "b.jpg"]);
    expect(g.targets).toEqual(["T1"]);
    expect(g.errors).toHaveLength(1);
  });
});
