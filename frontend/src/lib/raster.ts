/**
 * Rasters decoded in the browser (DSM heights, orthophoto bands) and what the map draws from them:
 * hillshade, colour ramps and the height difference of two surveys (volumes are the server's: POST
 * /runs/{id}/volumes measures a drawn outline as the volumes step does).
 * A Grid is north-up: row 0 is the top (maximum northing), cell (r, c) has its centre at
 * x = originX + (c + 0.5) resX, y = originY - (r + 0.5) resY.
 */

export interface Grid {
  width: number;
  height: number;
  data: Float32Array;
  originX: number;
  originY: number;
  resX: number;
  resY: number;
  /** NaN marks cells without data. */
}

export function cellCentre(g: Grid, r: number, c: number): [number, number] {
  return [g.originX + (c + 0.5) * g.resX, g.originY - (r + 0.5) * g.resY];
}

/** Nearest cell value at (x, y), NaN outside the grid or where there is no data. */
export function sampleNearest(g: Grid, x: number, y: number): number {
  const c = Math.floor((x - g.originX) / g.resX);
  const r = Math.floor((g.originY - y) / g.resY);
  if (c < 0 || r < 0 || c >= g.width || r >= g.height) return NaN;
  return g.data[r * g.width + c];
}

/** Bilinear height at (x, y) between cell centres; NaN when a neighbour lacks data. */
export function sampleBilinear(g: Grid, x: number, y: number): number {
  const fc = (x - g.originX) / g.resX - 0.5;
  const fr = (g.originY - y) / g.resY - 0.5;
  const c0 = Math.floor(fc), r0 = Math.floor(fr);
  const tx = fc - c0, ty = fr - r0;
  const at = (r: number, c: number) => {
    const rr = Math.min(g.height - 1, Math.max(0, r));
    const cc = Math.min(g.width - 1, Math.max(0, c));
    return g.data[rr * g.width + cc];
  };
  if (fc < -0.5 || fr < -0.5 || fc > g.width - 0.5 || fr > g.height - 0.5) return NaN;
  const v = (1 - ty) * ((1 - tx) * at(r0, c0) + tx * at(r0, c0 + 1)) + ty * ((1 - tx) * at(r0 + 1, c0) + tx * at(r0 + 1, c0 + 1));
  return v;
}

/** Value at a quantile (0..1) of the finite cells (sampled on large grids: exact enough for a ramp). */
export function quantiles(data: Float32Array, qs: number[], maxSamples = 200000): number[] {
  const step = Math.max(1, Math.floor(data.length / maxSamples));
  const v: number[] = [];
  for (let i = 0; i < data.length; i += step) if (Number.isFinite(data[i])) v.push(data[i]);
  if (!v.length) return qs.map(() => NaN);
  v.sort((a, b) => a - b);
  return qs.map((q) => v[Math.min(v.length - 1, Math.max(0, Math.round(q * (v.length - 1))))]);
}

/**
 * Hillshade (0..255) with the usual Horn gradient, sun azimuth (deg clockwise from north) and altitude.
 * Cells without data or on the edge use their available neighbours.
 */
export function hillshade(g: Grid, azimuthDeg = 315, altitudeDeg = 45, zFactor = 1): Uint8ClampedArray {
  const { width: w, height: h, data } = g;
  const out = new Uint8ClampedArray(w * h);
  // Unit vector towards the sun (x east, y north, z up); the surface normal is (-dz/dx, -dz/dy, 1).
  const az = (azimuthDeg * Math.PI) / 180, alt = (altitudeDeg * Math.PI) / 180;
  const sx = Math.sin(az) * Math.cos(alt), sy = Math.cos(az) * Math.cos(alt), sz = Math.sin(alt);
  const at = (r: number, c: number, fallback: number) => {
    if (r < 0 || c < 0 || r >= h || c >= w) return fallback;
    const v = data[r * w + c];
    return Number.isFinite(v) ? v : fallback;
  };
  for (let r = 0; r < h; r++) {
    for (let c = 0; c < w; c++) {
      const z = data[r * w + c];
      if (!Number.isFinite(z)) {
        out[r * w + c] = 0;
        continue;
      }
      const a = at(r - 1, c - 1, z), b = at(r - 1, c, z), cc = at(r - 1, c + 1, z);
      const d = at(r, c - 1, z), f = at(r, c + 1, z);
      const gg = at(r + 1, c - 1, z), hh = at(r + 1, c, z), ii = at(r + 1, c + 1, z);
      // dz/dx towards east, dz/dy towards north (row index grows southwards)
      const dzdx = ((cc + 2 * f + ii) - (a + 2 * d + gg)) / (8 * g.resX);
      const dzdy = ((a + 2 * b + cc) - (gg + 2 * hh + ii)) / (8 * g.resY);
      const gx = zFactor * dzdx, gy = zFactor * dzdy;
      const v = (-gx * sx - gy * sy + sz) / Math.sqrt(1 + gx * gx + gy * gy);
      out[r * w + c] = Math.max(0, Math.round(255 * v));
    }
  }
  return out;
}

export type RGB = [number, number, number];

/** Colour ramps as stops (position 0..1, colour). */
export const RAMPS: Record<string, [number, RGB][]> = {
  // Low green through yellow and brown to white: the classic hypsometric tints.
  terrain: [[0, [38, 115, 77]], [0.25, [125, 178, 90]], [0.5, [235, 220, 130]], [0.75, [176, 120, 70]], [1, [250, 250, 250]]],
  // Perceptually even, colour-blind safe (close to viridis).
  viridis: [[0, [68, 1, 84]], [0.25, [59, 82, 139]], [0.5, [33, 145, 140]], [0.75, [94, 201, 98]], [1, [253, 231, 37]]],
  // Change maps: blue = lower (cut), white = no change, red = higher (fill).
  diverging: [[0, [33, 102, 172]], [0.25, [103, 169, 207]], [0.5, [247, 247, 247]], [0.75, [239, 138, 98]], [1, [178, 24, 43]]],
};

export function rampColour(t: number, ramp: [number, RGB][]): RGB {
  if (!Number.isFinite(t)) return [0, 0, 0];
  const x = Math.min(1, Math.max(0, t));
  for (let i = 1; i < ramp.length; i++) {
    const [p1, c1] = ramp[i];
    if (x <= p1) {
      const [p0, c0] = ramp[i - 1];
      const u = p1 > p0 ? (x - p0) / (p1 - p0) : 0;
      return [0, 1, 2].map((k) => Math.round(c0[k] + u * (c1[k] - c0[k]))) as RGB;
    }
  }
  return ramp[ramp.length - 1][1];
}

export interface RenderOptions {
  min: number;
  max: number;
  ramp: keyof typeof RAMPS;
  /** Blend of the hillshade into the colour: 0 = flat colours, 1 = shade only. */
  shade: number;
}

/** RGBA pixels (for ImageData) of a height grid: colour ramp modulated by the hillshade. */
export function renderHeights(g: Grid, opts: RenderOptions, shade?: Uint8ClampedArray): Uint8ClampedArray {
  const { width: w, height: h, data } = g;
  const hs = opts.shade > 0 ? shade ?? hillshade(g) : null;
  const ramp = RAMPS[opts.ramp];
  const lut: RGB[] = [];
  for (let i = 0; i < 256; i++) lut.push(rampColour(i / 255, ramp));
  const span = opts.max - opts.min || 1;
  const out = new Uint8ClampedArray(w * h * 4);
  for (let i = 0; i < w * h; i++) {
    const z = data[i];
    if (!Number.isFinite(z)) continue; // transparent
    const t = Math.round(((z - opts.min) / span) * 255);
    const col = lut[Math.min(255, Math.max(0, t))];
    const s = hs ? 1 - opts.shade + (opts.shade * hs[i]) / 255 : 1;
    out[i * 4] = col[0] * s;
    out[i * 4 + 1] = col[1] * s;
    out[i * 4 + 2] = col[2] * s;
    out[i * 4 + 3] = 255;
  }
  return out;
}

/** Height change `later - earlier` on the later grid's cells (the earlier grid sampled bilinearly). */
export function difference(later: Grid, earlier: Grid): Grid {
  const out = new Float32Array(later.width * later.height);
  for (let r = 0; r < later.height; r++) {
    for (let c = 0; c < later.width; c++) {
      const [x, y] = cellCentre(later, r, c);
      const zb = sampleBilinear(earlier, x, y);
      const za = later.data[r * later.width + c];
      out[r * later.width + c] = Number.isFinite(za) && Number.isFinite(zb) ? za - zb : NaN;
    }
  }
  return { ...later, data: out };
}
