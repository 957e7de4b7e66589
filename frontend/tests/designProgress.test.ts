import { describe, expect, it } from "vitest";
import { area, type Ring } from "../src/lib/geom";
import { areaFromExtent, areaFromGeoJson, formatShare, netSeriesPoints, parseToleranceCm, type DesignProgress, type ProgressEntry } from "../src/lib/designProgress";

// GET /sites/{id}/design-progress as backend/services/designs.design_progress writes it
function entry(name: string, flown: string | null, net: number, sigma: number): ProgressEntry {
  return {
    survey_id: `sv-${name}`, survey_name: name, flown_at: flown, run_id: `run-${name}`, run_number: 1,
    cut_m3: net + 10, fill_m3: 10, net_m3: net, sigma_m3: { cut_m3: sigma * 0.8, fill_m3: sigma * 0.6, net_m3: sigma },
    on_grade_share: 0.42, on_grade_expected_share: 0.4, tolerance_m: 0.05, area_m2: 1200, warnings: [],
  };
}
const progress: DesignProgress = {
  design: { filename: "fg.xml", format: "landxml", sha256: "ab", key: "k", surface_name: null, area_m2: 1200, tolerance_m: 0.05 },
  conventions: "cut_m3: surveyed above design ...",
  surveys: [entry("June", "2024-06-24T08:10:05Z", 15.08, 0.21), entry("May", "2024-05-20T09:00:00Z", 31.5, 0.3), entry("Undated", null, 3, 0.1)],
  not_compared: [{ survey_id: "sv-x", survey_name: "April", flown_at: null, reason: "no successful run with the design step" }],
};

describe("design progress", () => {
  it("charts net ± 1σ at each flight, in time order, leaving undated surveys out", () => {
    const pts = netSeriesPoints(progress);
    expect(pts.map((p) => p.label)).toEqual(["May", "June"]);
    expect(pts.map((p) => [p.y, p.err])).toEqual([[31.5, 0.3], [15.08, 0.21]]);
    expect(pts[1].x).toBe(Date.UTC(2024, 5, 24, 8, 10, 5));
  });

  it("reads the tolerance in centimetres and refuses what the server would", () => {
    expect(parseToleranceCm("5")).toEqual({ value_m: 0.05 });
    expect(parseToleranceCm(" 2,5 ")).toEqual({ value_m: 0.025 });
    for (const bad of ["", "abc", "0", "-3", "2000"]) expect(parseToleranceCm(bad)).toHaveProperty("error");
    expect(formatShare(0.4234)).toBe("42 %");
    expect(formatShare(0.046)).toBe("4.6 %");
    expect(formatShare(null)).toBe("–");
  });

  it("makes the area from the design's extent: a closed counter-clockwise rectangle of the same area", () => {
    const a = areaFromExtent([679490, 3889220, 679560.5, 3889290])!;
    const ring = a.coordinates[0] as Ring;
    expect(ring[0]).toEqual(ring[ring.length - 1]);
    expect(area(ring.slice(0, -1))).toBeCloseTo(70.5 * 70, 6);
    expect(areaFromExtent([1, 2, 1, 5])).toBeNull();
    expect(areaFromExtent(undefined)).toBeNull();
  });

  it("reads an area from GeoJSON in the site CRS and says why one is refused", () => {
    const sq = (x: number, y: number, s: number) => [[x, y], [x + s, y], [x + s, y + s], [x, y + s], [x, y]];
    const fc = { type: "FeatureCollection", features: [sq(679500, 3889230, 10), sq(679520, 3889230, 10)].map((c, i) => ({ type: "Feature", properties: { name: `cell ${i}` }, geometry: { type: "Polygon", coordinates: [c] } })) };
    const two = areaFromGeoJson(JSON.stringify(fc), [679490, 3889220, 679560, 3889290]);
    expect(two.parts).toBe(2);
    expect(two.area.type).toBe("MultiPolygon");
    const one = areaFromGeoJson(JSON.stringify({ type: "Polygon", coordinates: [sq(679500, 3889230, 10)] }));
    expect(one.area.type).toBe("Polygon");
    expect(area((one.area.coordinates[0] as Ring).slice(0, -1))).toBeCloseTo(100, 9);
    expect(() => areaFromGeoJson(JSON.stringify({ type: "Polygon", coordinates: [sq(139.5, 35.1, 0.01)] }))).toThrow(/longitude\/latitude/);
    expect(() => areaFromGeoJson(JSON.stringify({ type: "Polygon", coordinates: [sq(100, 100, 10)] }), [679490, 3889220, 679560, 3889290])).toThrow(/outside the design/);
    const bowtie = [[679500, 3889230], [679510, 3889240], [679510, 3889230], [679500, 3889240], [679500, 3889230]];
    expect(() => areaFromGeoJson(JSON.stringify({ type: "Polygon", coordinates: [bowtie] }))).toThrow(/crosses itself/);
  });
});

describe("design change computed by a worker", () => {
  it("says pending while the worker computes it, done once stored, and from the totals otherwise", async () => {
    const { changeState } = await import("../src/lib/designProgress");
    expect(changeState({ surfaces_state: "queued", method: "totals" })).toMatchObject({ pending: true });
    expect(changeState({ surfaces_state: "running", method: "totals" }).label).toMatch(/^pending/);
    expect(changeState({ surfaces_state: "succeeded", method: "surfaces" })).toEqual({ label: "done: surface against surface", pending: false });
    expect(changeState({ surfaces_state: "failed", method: "totals" }).label).toMatch(/failed/);
    expect(changeState({ surfaces_state: null, method: "totals" })).toEqual({ label: "from the totals", pending: false });
  });

  it("asks again while the API answers 202 (changes_pending), backing off from 3 s to 60 s, and stops", async () => {
    const { progressPollDelayMs } = await import("../src/lib/designProgress");
    expect(progressPollDelayMs({ changes_pending: false }, 0)).toBeNull();
    expect(progressPollDelayMs(null, 0)).toBeNull();
    expect([0, 1, 2, 3, 4, 5, 9].map((n) => progressPollDelayMs({ changes_pending: true }, n))).toEqual([3000, 6000, 12000, 24000, 48000, 60000, 60000]);
    expect(progressPollDelayMs({ changes_pending: true }, 40)).toBeNull();
  });
});
