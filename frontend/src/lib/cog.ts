/**
 * Cloud-optimised GeoTIFFs (DSM, orthophoto) read in the browser with geotiff.js over HTTP range
 * requests: only the overview level that fits the screen, and only the window that is shown, is
 * fetched. Mask IFDs (GDAL internal masks) are never taken for image data.
 */

import { type GeoTIFF, type GeoTIFFImage, fromUrl } from "geotiff";
import type { BBox } from "./geom";
import type { Grid } from "./raster";

export interface CogInfo {
  tiff: GeoTIFF;
  images: GeoTIFFImage[]; // full resolution first, then overviews, largest to smallest
  bbox: BBox;
  width: number;
  height: number;
  resX: number;
  resY: number;
  bands: number;
  nodata: number | null;
  epsg: number | null;
}

const cache = new Map<string, Promise<CogInfo>>();

export function openCog(url: string): Promise<CogInfo> {
  let p = cache.get(url);
  if (!p) {
    p = (async () => {
      const tiff = await fromUrl(url, { allowFullFile: true, cacheSize: 200 });
      const n = await tiff.getImageCount();
      const images: GeoTIFFImage[] = [];
      for (let i = 0; i < n; i++) {
        const im = await tiff.getImage(i);
        const nst = (im.fileDirectory as any).NewSubfileType ?? 0;
        if (i === 0 || ((nst & 1) && !(nst & 4))) images.push(im);
      }
      const first = images[0];
      const [x0, y0, x1, y1] = first.getBoundingBox();
      const [rx, ry] = first.getResolution();
      const geoKeys = (first as any).geoKeys ?? {};
      return {
        tiff, images: images.sort((a, b) => b.getWidth() - a.getWidth()),
        bbox: { minX: x0, minY: y0, maxX: x1, maxY: y1 },
        width: first.getWidth(), height: first.getHeight(), resX: Math.abs(rx), resY: Math.abs(ry),
        bands: first.getSamplesPerPixel(), nodata: first.getGDALNoData(),
        epsg: geoKeys.ProjectedCSTypeGeoKey ?? geoKeys.GeographicTypeGeoKey ?? null,
      };
    })();
    p.catch(() => cache.delete(url));
    cache.set(url, p);
  }
  return p;
}

export interface RasterWindow {
  bbox: BBox;
  width: number;
  height: number;
}

/** The window of `want` (clipped to the raster) sampled at about `pxPerM` pixels per metre. */
export function windowFor(info: CogInfo, want: BBox, pxPerM: number, maxDim = 2048): RasterWindow | null {
  const b: BBox = {
    minX: Math.max(info.bbox.minX, want.minX), minY: Math.max(info.bbox.minY, want.minY),
    maxX: Math.min(info.bbox.maxX, want.maxX), maxY: Math.min(info.bbox.maxY, want.maxY),
  };
  if (b.maxX <= b.minX || b.maxY <= b.minY) return null;
  // never finer than the raster itself, never more than maxDim pixels a side
  const ppm = Math.min(pxPerM, 1 / info.resX, maxDim / (b.maxX - b.minX), maxDim / (b.maxY - b.minY));
  return { bbox: b, width: Math.max(1, Math.round((b.maxX - b.minX) * ppm)), height: Math.max(1, Math.round((b.maxY - b.minY) * ppm)) };
}

async function readWindow(info: CogInfo, w: RasterWindow, signal?: AbortSignal) {
  // The smallest overview that still has at least the requested resolution.
  const needRes = (w.bbox.maxX - w.bbox.minX) / w.width;
  let img = info.images[0];
  for (const im of info.images) {
    const res = ((info.bbox.maxX - info.bbox.minX) / im.getWidth());
    if (res <= needRes * 1.0001) img = im;
  }
  const sx = img.getWidth() / (info.bbox.maxX - info.bbox.minX);
  const sy = img.getHeight() / (info.bbox.maxY - info.bbox.minY);
  const win = [
    Math.max(0, Math.floor((w.bbox.minX - info.bbox.minX) * sx)),
    Math.max(0, Math.floor((info.bbox.maxY - w.bbox.maxY) * sy)),
    Math.min(img.getWidth(), Math.ceil((w.bbox.maxX - info.bbox.minX) * sx)),
    Math.min(img.getHeight(), Math.ceil((info.bbox.maxY - w.bbox.minY) * sy)),
  ];
  // The window actually read, in world coordinates (pixel-aligned on the chosen level).
  const bbox: BBox = {
    minX: info.bbox.minX + win[0] / sx, maxX: info.bbox.minX + win[2] / sx,
    maxY: info.bbox.maxY - win[1] / sy, minY: info.bbox.maxY - win[3] / sy,
  };
  const rasters = (await img.readRasters({ window: win, width: w.width, height: w.height, resampleMethod: "nearest", interleave: false, signal } as any)) as any;
  return { rasters, bbox, width: w.width, height: w.height };
}

/** Heights (first band) of a window as a Grid with NaN for no data. */
export async function readGrid(info: CogInfo, w: RasterWindow, signal?: AbortSignal): Promise<Grid> {
  const r = await readWindow(info, w, signal);
  const band = r.rasters[0] as ArrayLike<number>;
  const data = new Float32Array(r.width * r.height);
  const nd = info.nodata;
  for (let i = 0; i < data.length; i++) {
    const v = band[i];
    data[i] = (nd !== null && v === nd) || !Number.isFinite(v) || v < -1e30 ? NaN : v;
  }
  return { width: r.width, height: r.height, data, originX: r.bbox.minX, originY: r.bbox.maxY, resX: (r.bbox.maxX - r.bbox.minX) / r.width, resY: (r.bbox.maxY - r.bbox.minY) / r.height };
}

/** RGBA pixels of an image window (1 band: grey; 3: RGB; 4: RGB + alpha; nodata / all-zero: clear). */
export async function readRgba(info: CogInfo, w: RasterWindow, signal?: AbortSignal): Promise<{ rgba: Uint8ClampedArray; width: number; height: number; bbox: BBox }> {
  const r = await readWindow(info, w, signal);
  const n = r.width * r.height;
  const out = new Uint8ClampedArray(n * 4);
  const b = r.rasters as ArrayLike<number>[];
  const nb = b.length;
  const nd = info.nodata;
  const scale = b[0] instanceof Uint16Array ? 1 / 256 : 1;
  for (let i = 0; i < n; i++) {
    const rr = b[0][i], gg = nb >= 3 ? b[1][i] : rr, bb = nb >= 3 ? b[2][i] : rr;
    let a = nb >= 4 ? b[3][i] * scale : 255;
    if (nd !== null && rr === nd && gg === nd && bb === nd) a = 0;
    if (nb < 4 && rr === 0 && gg === 0 && bb === 0) a = 0;
    out[i * 4] = rr * scale;
    out[i * 4 + 1] = gg * scale;
    out[i * 4 + 2] = bb * scale;
    out[i * 4 + 3] = a;
  }
  return { rgba: out, width: r.width, height: r.height, bbox: r.bbox };
}

export function canvasOf(rgba: Uint8ClampedArray, width: number, height: number): HTMLCanvasElement {
  const c = document.createElement("canvas");
  c.width = width;
  c.height = height;
  c.getContext("2d")!.putImageData(new ImageData(rgba as unknown as Uint8ClampedArray<ArrayBuffer>, width, height), 0, 0);
  return c;
}
