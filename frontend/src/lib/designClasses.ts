/**
 * The design step's cut/fill classes (design/classes.tif, docs/design.md): the codes the step writes, their
 * colours and names, and the map's rendering of a classes grid. Colours are those of the file's colour table.
 */

import type { Grid } from "./raster";

export interface DesignClass {
  code: number;
  key: string;
  label: string;
  rgb: [number, number, number];
}

/** Code 0 (outside the design area) is transparent. */
export const DESIGN_CLASSES: DesignClass[] = [
  { code: 1, key: "cut", label: "Cut (above design)", rgb: [214, 39, 40] },
  { code: 2, key: "fill", label: "Fill (below design)", rgb: [31, 119, 180] },
  { code: 3, key: "on_grade", label: "On grade (within tolerance)", rgb: [44, 160, 44] },
  { code: 4, key: "not_significant", label: "Not significant (within the survey's uncertainty)", rgb: [190, 190, 190] },
  { code: 5, key: "no_data", label: "No data", rgb: [60, 60, 60] },
];

const BY_CODE = new Map(DESIGN_CLASSES.map((c) => [c.code, c]));

/** RGBA pixels of a classes grid (codes 1..5; 0, NaN and unknown codes transparent). */
export function renderDesignClasses(g: Grid, alpha = 200): Uint8ClampedArray {
  const out = new Uint8ClampedArray(g.width * g.height * 4);
  for (let i = 0; i < g.data.length; i++) {
    const c = BY_CODE.get(g.data[i]);
    if (!c) continue;
    out[i * 4] = c.rgb[0];
    out[i * 4 + 1] = c.rgb[1];
    out[i * 4 + 2] = c.rgb[2];
    out[i * 4 + 3] = alpha;
  }
  return out;
}

/** The class name under a cell value, or null. */
export function designClassOf(v: number): DesignClass | null {
  return BY_CODE.get(v) ?? null;
}
