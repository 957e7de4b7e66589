import { describe, expect, it } from "vitest";
import { area, outlinesFromGeoJson, perimeter, pointInRing, ringToGeoJson, selfIntersects, signedArea } from "../src/lib/geom";
import { type Grid, difference, hillshade, quantiles, rampColour, RAMPS, renderHeights, sampleBilinear } from "../src/lib/raster";

/** A grid of `size` metres with 0.1 m cells, heights from f(x, y) at cell centres. */
function grid(f: (x: number, y: number) => number, size = 20, res = 0.1, x0 = 1000, y0 = 5000): Grid {
  const n = Math.round(size / res);
  const data = new Float32Array(n * n);
  for (let r = 0; r < n; r++) for (let c = 0; c < n; c++) data[r * n + c] = f(x0 + (c + 0.5) * res, y0 + size - (r + 0.5) * res);
  return { width: n, height: n, data, originX: x0, originY: y0 + size, resX: res, resY: res };
}

const square = (x: number, y: number, s: number): [number, number][] => [[x, y], [x + s, y], [x + s, y + s], [x, y + s]];

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
