/**
 * The run's cut/fill to the site's design on the map: design/classes.tif (cut / fill / on grade / not
 * significant) read from the run's COG at the overview that fits the map, and design/difference.tif on the
 * same window for the readout (surveyed minus design, metres).
 */

import { useEffect, useState } from "preact/hooks";
import { api, apiUrl } from "../api/client";
import type { Run, RunDetail } from "../api/types";
import { useLoad } from "../hooks";
import type { RasterLayer } from "../components/MapView";
import { canvasOf, openCog, readGrid, windowFor } from "../lib/cog";
import { renderDesignClasses } from "../lib/designClasses";
import type { Grid } from "../lib/raster";
import { OVERVIEW_PX, gridBBox } from "./rasterLayers";

/** The design step's summary when the run compared its surface with a design (not skipped), else null. */
export function designSummary(run: RunDetail | null | undefined): Record<string, any> | null {
  const st = run?.step_details?.find((s) => s.name === "design");
  if (!st || !st.summary || st.summary.skipped || !["succeeded", "skipped"].includes(st.state)) return null;
  return st.summary;
}

/** designSummary of a run, its details loaded when the run has a design step. */
export function useDesignSummary(run: Run): Record<string, any> | null {
  const has = run.steps.includes("design");
  const detail = useLoad((signal) => (has ? api.get<RunDetail>(`/runs/${run.id}`, { signal }) : Promise.resolve(null)), [run.id, has, run.state]);
  return designSummary(detail.data);
}

export interface DesignLayerState {
  layer: RasterLayer | null;
  classes: Grid | null;
  difference: Grid | null;
  error: Error | null;
  loading: boolean;
}

const none: DesignLayerState = { layer: null, classes: null, difference: null, error: null, loading: false };

/** The layer of `runId` (null: the run has no cut/fill to design). */
export function useDesignLayer(runId: string | null, enabled: boolean): DesignLayerState {
  const [st, setSt] = useState<DesignLayerState>(none);
  useEffect(() => {
    setSt(none);
    if (!runId || !enabled) return;
    const ac = new AbortController();
    setSt({ ...none, loading: true });
    (async () => {
      try {
        const info = await openCog(apiUrl(`/runs/${runId}/results/files/design/classes.tif`));
        const w = windowFor(info, info.bbox, Infinity, OVERVIEW_PX)!;
        const classes = await readGrid(info, w, ac.signal);
        let difference: Grid | null = null;
        try {
          const dInfo = await openCog(apiUrl(`/runs/${runId}/results/files/design/difference.tif`));
          difference = await readGrid(dInfo, { bbox: gridBBox(classes), width: classes.width, height: classes.height }, ac.signal);
        } catch {
          /* the readout's number is a nicety: the classes are the layer */
        }
        if (ac.signal.aborted) return;
        const layer = { id: "design-classes", canvas: canvasOf(renderDesignClasses(classes), classes.width, classes.height), bbox: gridBBox(classes), opacity: 0.85 };
        setSt({ layer, classes, difference, error: null, loading: false });
      } catch (e) {
        if (!ac.signal.aborted) setSt({ ...none, error: e as Error });
      }
    })();
    return () => ac.abort();
  }, [runId, enabled]);
  return st;
}
