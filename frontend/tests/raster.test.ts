import { describe, expect, it } from "vitest";
import { area, outlinesFromGeoJson, perimeter, pointInRing, ringToGeoJson, selfIntersects, signedArea } from "../src/lib/geom";
import { type Grid, difference, fitPlane, hillshade, quantiles, rampColour, RAMPS, renderHeights, sampleBilinear, volumeUnderOutline } from "../src/lib/raster";

/** A grid of `size` metres with 0.1 m cells, heights from f(x, y) at cell centres. */
function grid(f: (x: number, y: number) => number, size = 20, res = 0.1, x0 = 1000, y0 = 5000): Grid {
  const n = Math.round(size / res);
  const data = new Float32Array(n * n);
  for (let r = 0; r < n; r++) for (let c = 0; c < n; c++) data[r * n + c] = f(x0 + (c + 0.5) * res, y0 + size - (r + 0.5) * res);
  return { width: n, height: n, data, originX: x0, originY: y0 + size, resX: res, resY: res };
}

const square = (x: number, y: number, s: number): [number, number][] => [[x, y], [x + s, y], [x + s, y + s], [x, y + s]];

describe("volumes under an outline (browser estimate)", () => {
  it("measures a cone on a flat base within 1 %", () => {
    const R = 6, H = 3, cx = 1010, cy = 5010, z0 = 100;
    const g = grid((x, y) => z0 + Math.max(0, H * (1 - Math.hypot(x - cx, y - cy) / R)));
    const v = volumeUnderOutline(g, square(1002, 5002, 16), "lowest", 0.02);
    const truth = (Math.PI * R * R * H) / 3;
    expect(Math.abs(v.cut_m3 - truth) / truth).toBeLessThan(0.01);
    expect(v.fill_m3).toBeCloseTo(0, 6);
    expect(v.baseHeight_m).toBeCloseTo(z0, 4);
    expect(v.area_m2).toBeCloseTo(256, 6);
    expect(v.sigma_m3).toBeCloseTo(256 * 0.02, 3); // flat outline: only the survey's vertical error
  });

  it("measures a box on an inclined ground with a plane base, and cut/fill against an elevation", () => {
    const slope = (x: number, y: number) => 50 + 0.1 * (x - 1000) + 0.05 * (y - 5000);
    const g = grid((x, y) => slope(x, y) + (x > 1006 && x < 1014 && y > 5006 && y < 5014 ? 2 : 0));
    const v = volumeUnderOutline(g, square(1003, 5003, 14), "plane");
    expect(v.cut_m3).toBeCloseTo(64 * 2, 0);
    const flat = grid(() => 10);
    const e = volumeUnderOutline(flat, square(1002, 5002, 10), { elevation: 10.5 });
    expect(e.fill_m3).toBeCloseTo(50, 6);
    expect(e.net_m3).toBeCloseTo(-50, 6);
  });

  it("counts cells without data instead of treating them as zero", () => {
    const g = grid(() => 1);
    for (let i = 0; i < 100; i++) g.data[10050 + i] = NaN;
    const v = volumeUnderOutline(g, square(1000.05, 5000.05, 19.9), { elevation: 0 });
    expect(v.missingCells).toBe(100);
  });

  it("fits a plane exactly through planar samples", () => {
    const s = [0, 1, 2, 3, 4].flatMap((i) => [0, 1, 2].map((j) => ({ x: i, y: j, z: 3 + 0.5 * i - 0.25 * j })));
    const p = fitPlane(s);
    expect(p.rms).toBeLessThan(1e-9);
    expect(p.at(10, 10)).toBeCloseTo(3 + 5 - 2.5, 9);
  });
});

describe("map rendering", () => {
  it("shades slopes facing the sun brighter than those facing away", () => {
    const east = grid((x) => 0.5 * (x - 1000), 4); // rises to the east: faces west
    const west = grid((x) => -0.5 * (x - 1000), 4);
    const flat = grid(() => 0, 4);
    const mid = 20 * 40 + 20;
    const [e, w, f] = [hillshade(east, 270)[mid], hillshade(west, 270)[mid], hillshade(flat, 270)[mid]];
    expect(e).toBeGreaterThan(f);
    expect(w).toBeLessThan(f);
    expect(f).toBe(Math.round(255 * Math.sin(Math.PI / 4)));
  });

  it("interpolates colour ramps and leaves no-data cells transparent", () => {
    expect(rampColour(0, RAMPS.diverging)).toEqual([33, 102, 172]);
    expect(rampColour(0.5, RAMPS.diverging)).toEqual([247, 247, 247]);
    expect(rampColour(2, RAMPS.viridis)).toEqual([253, 231, 37]);
    const g = grid(() => 5, 1);
    g.data[0] = NaN;
    const px = renderHeights(g, { min: 0, max: 10, ramp: "viridis", shade: 0 });
    expect(px[3]).toBe(0);
    expect(px[7]).toBe(255);
    expect([px[4], px[5], px[6]]).toEqual(rampColour(128 / 255, RAMPS.viridis));
  });

  it("differences two surveys on different grids", () => {
    const a = grid((x, y) => 0.01 * x + 0.02 * y + 1, 10, 0.1);
    const b = grid((x, y) => 0.01 * x + 0.02 * y, 12, 0.25, 999, 4999);
    const d = difference(a, b);
    const q = quantiles(d.data, [0, 1]);
    expect(q[0]).toBeCloseTo(1, 3);
    expect(q[1]).toBeCloseTo(1, 3);
    expect(sampleBilinear(b, 1005.3, 5004.1)).toBeCloseTo(0.01 * 1005.3 + 0.02 * 5004.1, 3);
  });
});

describe("geometry", () => {
  it("computes area, orientation, perimeter and containment", () => {
    const sq = square(0, 0, 2);
    expect(signedArea(sq)).toBe(4);
    expect(area([...sq].reverse())).toBe(4);
    expect(perimeter(sq)).toBe(8);
    expect(pointInRing(1, 1, sq)).toBe(true);
    expect(pointInRing(3, 1, sq)).toBe(false);
    expect(selfIntersects(sq)).toBe(false);
    expect(selfIntersects([[0, 0], [2, 2], [2, 0], [0, 2]])).toBe(true);
  });

  it("imports GeoJSON outlines and refuses longitude/latitude", () => {
    const fc = { type: "FeatureCollection", features: [{ type: "Feature", properties: { name: "Sand" }, geometry: { type: "Polygon", coordinates: [[[679480, 3889230], [679490, 3889230], [679490, 3889240], [679480, 3889230]]] } }] };
    const o = outlinesFromGeoJson(JSON.stringify(fc));
    expect(o).toHaveLength(1);
    expect(o[0].name).toBe("Sand");
    expect(o[0].ring).toHaveLength(3);
    expect(() => outlinesFromGeoJson('{"type":"Polygon","coordinates":[[[139.1,35.1],[139.2,35.1],[139.2,35.2],[139.1,35.1]]]}')).toThrow(/longitude/);
    expect(() => outlinesFromGeoJson("nope")).toThrow(/not JSON/);
    const gj = ringToGeoJson([[0, 0], [0, 1], [1, 1]]);
    expect(gj.coordinates[0]).toHaveLength(4);
    expect(signedArea(gj.coordinates[0].slice(0, 3) as [number, number][])).toBeGreaterThan(0);
  });
});
