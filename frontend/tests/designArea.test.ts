/**
 * The design area drawn on the site map (MapTab: lib/designProgress.designAreaOutlines) and the change since the
 * previous survey in the design panel (design-progress `since_previous`, formatChange).
 */

import { describe, expect, it } from "vitest";
import { area, type Ring } from "../src/lib/geom";
import { designAreaOutlines, formatChange, type SiteDesign } from "../src/lib/designProgress";

const sq = (x: number, y: number, s: number) => [[x, y], [x + s, y], [x + s, y + s], [x, y + s], [x, y]];

describe("the design area on the map", () => {
  it("draws a polygon's outer ring and its hole as outlines of kind design, named once", () => {
    const d = { filename: "fg.xml", area: { type: "Polygon", coordinates: [sq(679500, 3889230, 40), sq(679510, 3889240, 5)] } } as Pick<SiteDesign, "area" | "filename">;
    const o = designAreaOutlines(d);
    expect(o.map((x) => x.kind)).toEqual(["design", "design"]);
    expect(o[0].name).toBe("Design area (fg.xml)");
    expect(o[1].name).toBe("");
    // open rings (the closing corner dropped) of the areas given
    expect(o[0].ring.length).toBe(4);
    expect(area(o[0].ring as Ring)).toBeCloseTo(1600, 9);
    expect(area(o[1].ring as Ring)).toBeCloseTo(25, 9);
    expect(new Set(o.map((x) => x.id)).size).toBe(2);
  });

  it("draws every part of a MultiPolygon and leaves out what cannot be drawn", () => {
    const multi = { filename: "fg.dxf", area: { type: "MultiPolygon", coordinates: [[sq(0, 0, 10)], [sq(20, 0, 10)], [[[1, 1], [2, 2], [1, 1]]], [[[0, 0], ["x", 1], [1, 1], [0, 0]]]] } } as unknown as SiteDesign;
    const o = designAreaOutlines(multi);
    expect(o.length).toBe(2);
    expect(o[1].ring[0]).toEqual([20, 0]);
    expect(designAreaOutlines({ filename: "fg.xml", area: null })).toEqual([]);
    expect(designAreaOutlines(null)).toEqual([]);
  });
});

describe("the change since the previous survey", () => {
  it("is written signed with its sigma, or a dash when unknown", () => {
    expect(formatChange(22.6173, 0.4121)).toBe("+22.6 ± 0.4");
    expect(formatChange(-13.09, null)).toBe("−13.1");
    expect(formatChange(-1234.5, 12.3)).toBe("−1235 ± 12");
    expect(formatChange(null, 1)).toBe("–");
  });
});
