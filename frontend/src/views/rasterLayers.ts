/**
 * Raster layers of a run for the map: the orthophoto and the shaded DSM, read from the run's COGs at
 * the overview level that fits the map, plus a finer window of what is on screen after zooming in.
 */

import { useEffect, useRef, useState } from "preact/hooks";
import { apiUrl } from "../api/client";
import { type CogInfo, canvasOf, openCog, readGrid, readRgba, windowFor } from "../lib/cog";
import type { BBox } from "../lib/geom";
import { type Grid, type RenderOptions, hillshade, quantiles, renderHeights } from "../lib/raster";
import type { RasterLayer } from "../components/MapView";

export const OVERVIEW_PX = 1600;

export interface LayerState {
  info: CogInfo | null;
  overview: RasterLayer | null;
  detail: RasterLayer | null;
  grid: Grid | null;
  detailGrid: Grid | null;
  error: Error | null;
  loading: boolean;
}

const empty: LayerState = { info: null, overview: null, detail: null, grid: null, detailGrid: null, error: null, loading: false };

function gridCanvas(g: Grid, opts: RenderOptions): HTMLCanvasElement {
  const shade = opts.shade > 0 ? hillshade(g) : undefined;
  return canvasOf(renderHeights(g, opts, shade), g.width, g.height);
}

export function gridBBox(g: Grid): BBox {
  return { minX: g.originX, maxX: g.originX + g.width * g.resX, maxY: g.originY, minY: g.originY - g.height * g.resY };
}

/** Auto colour range of a height grid: 2nd to 98th percentile. */
export function autoRange(g: Grid | null): [number, number] | null {
  if (!g) return null;
  const [a, b] = quantiles(g.data, [0.02, 0.98]);
  return Number.isFinite(a) && Number.isFinite(b) ? [a, b === a ? a + 1 : b] : null;
}

/**
 * A run's raster (`what` = "dsm" or "ortho") as map layers. `render` options apply to the DSM.
 * Returns the state and a `viewChanged(bbox, pxPerM)` to pass to the map.
 */
export function useRunRaster(runId: string | null, what: "dsm" | "ortho", enabled: boolean, render?: RenderOptions) {
  const [st, setSt] = useState<LayerState>(empty);
  const detailAbort = useRef<AbortController | null>(null);
  const url = runId ? apiUrl(`/runs/${runId}/results/${what}`) : null;

  useEffect(() => {
    setSt(empty);
    if (!url || !enabled) return;
    const ac = new AbortController();
    setSt({ ...empty, loading: true });
    (async () => {
      try {
        const info = await openCog(url);
        const w = windowFor(info, info.bbox, Infinity, OVERVIEW_PX)!;
        if (what === "dsm") {
          const grid = await readGrid(info, w, ac.signal);
          if (!ac.signal.aborted) setSt({ ...empty, info, grid });
        } else {
          const r = await readRgba(info, w, ac.signal);
          if (!ac.signal.aborted) setSt({ ...empty, info, overview: { id: `${what}-overview`, canvas: canvasOf(r.rgba, r.width, r.height), bbox: r.bbox } });
        }
      } catch (e) {
        if (!ac.signal.aborted) setSt({ ...empty, error: e as Error });
      }
    })();
    return () => ac.abort();
  }, [url, enabled]);

  // DSM: (re)render the overview and detail grids with the current colour options.
  const key = render ? `${render.min}|${render.max}|${render.ramp}|${render.shade}` : "";
  useEffect(() => {
    if (what !== "dsm" || !render || !st.grid) return;
    setSt((s) => ({
      ...s,
      overview: s.grid ? { id: "dsm-overview", canvas: gridCanvas(s.grid, render), bbox: gridBBox(s.grid) } : null,
      detail: s.detailGrid ? { id: "dsm-detail", canvas: gridCanvas(s.detailGrid, render), bbox: gridBBox(s.detailGrid) } : null,
    }));
  }, [key, st.grid, st.detailGrid]);

  const viewChanged = (view: BBox, pxPerM: number) => {
    const info = st.info;
    if (!info || !enabled) return;
    const overviewPpm = Math.min(OVERVIEW_PX / (info.bbox.maxX - info.bbox.minX), OVERVIEW_PX / (info.bbox.maxY - info.bbox.minY));
    const rasterPpm = 1 / info.resX;
    if (pxPerM < overviewPpm * 1.4 || overviewPpm >= rasterPpm) {
      if (st.detail || st.detailGrid) setSt((s) => ({ ...s, detail: null, detailGrid: null }));
      return;
    }
    const mx = (view.maxX - view.minX) * 0.25, my = (view.maxY - view.minY) * 0.25;
    const w = windowFor(info, { minX: view.minX - mx, maxX: view.maxX + mx, minY: view.minY - my, maxY: view.maxY + my }, pxPerM, 2400);
    if (!w) return;
    detailAbort.current?.abort();
    const ac = new AbortController();
    detailAbort.current = ac;
    (async () => {
      try {
        if (what === "dsm") {
          const g = await readGrid(info, w, ac.signal);
          if (!ac.signal.aborted) setSt((s) => ({ ...s, detailGrid: g }));
        } else {
          const r = await readRgba(info, w, ac.signal);
          if (!ac.signal.aborted) setSt((s) => ({ ...s, detail: { id: `${what}-detail`, canvas: canvasOf(r.rgba, r.width, r.height), bbox: r.bbox } }));
        }
      } catch {
        /* a finer window is a nicety: keep the overview */
      }
    })();
  };

  return { ...st, viewChanged };
}

/** The height under (x, y) from the finest grid loaded. */
export function heightAt(grids: (Grid | null)[], x: number, y: number): number | null {
  for (const g of grids) {
    if (!g) continue;
    const c = Math.floor((x - g.originX) / g.resX), r = Math.floor((g.originY - y) / g.resY);
    if (c >= 0 && r >= 0 && c < g.width && r < g.height) {
      const v = g.data[r * g.width + c];
      if (Number.isFinite(v)) return v;
    }
  }
  return null;
}
