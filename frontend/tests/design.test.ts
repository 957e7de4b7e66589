import { describe, expect, it } from "vitest";
import { fromArrayBuffer } from "geotiff";
import { DESIGN_CLASSES, designClassOf, renderDesignClasses } from "../src/lib/designClasses";
import { designSummary } from "../src/views/designLayer";
import type { Grid } from "../src/lib/raster";
import type { RunDetail } from "../src/api/types";
import { fixture, fixtureText } from "./helpers";

// design_classes.tif: the design step's classes COG of the valley scene (tests/design/scenes.py), made by the
// core (PROVENANCE.txt); design_classes.json: the class areas the step computed for it
async function classesGrid(): Promise<{ grid: Grid; colormap: number[] }> {
  const bytes = fixture("design_classes.tif");
  const tiff = await fromArrayBuffer(bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength) as ArrayBuffer);
  const im = await tiff.getImage(0);
  const [band] = (await im.readRasters({ interleave: false })) as unknown as ArrayLike<number>[];
  const data = new Float32Array(band.length);
  for (let i = 0; i < data.length; i++) data[i] = band[i] === 0 ? NaN : band[i];
  const [x0, , , y1] = im.getBoundingBox();
  const [rx, ry] = im.getResolution();
  const grid = { width: im.getWidth(), height: im.getHeight(), data, originX: x0, originY: y1, resX: Math.abs(rx), resY: Math.abs(ry) };
  return { grid, colormap: Array.from((im.fileDirectory as any).ColorMap as ArrayLike<number>) };
}

describe("cut/fill to design on the map", () => {
  it("draws each class in the colour of the file's own colour table, outside the area transparent", async () => {
    const { grid, colormap } = await classesGrid();
    const n = colormap.length / 3; // TIFF colour map: all reds, then greens, then blues (16 bit)
    for (const c of DESIGN_CLASSES) {
      expect([colormap[c.code], colormap[n + c.code], colormap[2 * n + c.code]].map((v) => Math.round(v / 257))).toEqual(c.rgb);
    }
    const rgba = renderDesignClasses(grid);
    const counts = new Map<string, number>();
    let clear = 0, wrong = 0;
    for (let i = 0; i < grid.data.length; i++) {
      const cls = designClassOf(grid.data[i]);
      if (!cls) {
        if (rgba[i * 4 + 3] !== 0) wrong++;
        clear++;
        continue;
      }
      if (rgba[i * 4] !== cls.rgb[0] || rgba[i * 4 + 1] !== cls.rgb[1] || rgba[i * 4 + 2] !== cls.rgb[2] || rgba[i * 4 + 3] === 0) wrong++;
      counts.set(cls.key, (counts.get(cls.key) ?? 0) + 1);
    }
    expect(wrong).toBe(0);
    expect(clear).toBeGreaterThan(0); // the corners outside the hexagon
    // the areas the map shows are those the step computed (edge cells count whole on the map: on grade is
    // the class along the polygon's edge, so its area is a little larger there)
    const want = JSON.parse(fixtureText("design_classes.json")) as { classes_m2: Record<string, number>; cell_size_m: number };
    const cell = want.cell_size_m ** 2;
    for (const key of ["cut", "fill"]) expect(Math.abs((counts.get(key) ?? 0) * cell - want.classes_m2[key])).toBeLessThan(0.005 * want.classes_m2[key]);
    const onGrade = (counts.get("on_grade") ?? 0) * cell;
    expect(onGrade).toBeGreaterThanOrEqual(want.classes_m2.on_grade);
    expect(onGrade).toBeLessThan(want.classes_m2.on_grade * 1.02);
    expect(Math.abs((counts.get("not_significant") ?? 0) * cell - want.classes_m2.not_significant)).toBeLessThan(0.5);
  });

  it("offers the layer only for a run whose design step compared with a design", () => {
    const run = (summary: Record<string, any> | null, state = "succeeded") =>
      ({ step_details: [{ name: "design", state, summary }] }) as unknown as RunDetail;
    expect(designSummary(run({ skipped: true, reason: "the site has no design surface" }, "skipped"))).toBeNull();
    expect(designSummary(run(null, "failed"))).toBeNull();
    expect(designSummary(run({ cut_m3: 37.7 }))?.cut_m3).toBe(37.7);
    expect(designSummary(run({ cut_m3: 12 }, "skipped"))?.cut_m3).toBe(12); // reused from an earlier run
    expect(designSummary(undefined)).toBeNull();
  });
});
